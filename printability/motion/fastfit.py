"""Exact shortcut for "does this swept footprint lie inside the target?".

:func:`printability.motion.footprints.fits` asks ``shapely.covers(G, P)``
for hundreds of thousands of convex swept polygons P (64 vertices each) per
part. GEOS answers each with a general overlay-style test (noding P's ring
against ∂G); for a convex P known as an intersection of half-planes
``u_j·x ≤ h_j`` a far cheaper test is exact: clip each nearby edge of ∂G
against those half-planes (Liang–Barsky, one pass over the 64 half-planes).

For one footprint P (the polygon of the ring ``shapely.covers`` would be
given; its vertices lie within rounding, δ ≪ ε = 1e-9 mm, of the half-plane
polygon):

* **Reject** when one vertex of P lies strictly outside G
  (``shapely.intersects_xy`` false), or when some edge of ∂G has a piece of
  positive length inside every half-plane shrunk by ε: that piece is a point
  of ∂G in the interior of P, and every neighbourhood of a boundary point
  holds points outside G, so P ⊄ G.
* **Accept** when a vertex of P lies in G and no edge of ∂G meets the
  half-planes grown by ε (which contain P): P is connected, holds a point of
  G and meets no point of ∂G, so it lies in the interior of G.
* Otherwise (∂G grazes P within ε) ``shapely.covers`` decides.

Each decision is therefore the one ``shapely.covers`` gives; only the time
changes. Edges near P are found with a uniform grid over ∂G's edges, built
once per layer target.
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from printability.motion._kernels import cell_of as _cell
from printability.motion._kernels import point_segment2 as _point_segment2
from printability.motion._kernels import segments2 as _segments2
from printability.motion.beadunion import BeadUnion, in_polygons, union_contains_xy, union_covers

__all__ = ["EPS", "boundary_grid", "contains_xy", "covers", "covers_rings", "first_fits",
           "locator", "swept_kernel"]

EPS = 1e-9
"""Margin (mm) of the half-plane tests against rounding of the ring's vertices."""

# The helpers called per footprint or per edge only read and write arrays they are given:
# they are compiled without the runtime (``_nrt=False``), else every call increfs and
# decrefs each array argument (atomic operations that cost more than a footprint's test).

_cache: list[tuple[BaseGeometry, tuple]] = []


def boundary_grid(target: BaseGeometry | BeadUnion) -> tuple:
    """Edges of ∂G binned on a uniform grid (CSR), cached for the last few targets.

    ``target`` is a shapely geometry or a :class:`~printability.motion.beadunion.BeadUnion`
    (whose boundary edges are already computed).

    Returns
    -------
    tuple
        ``(ex0, ey0, ex1, ey1, start, items, x0, y0, cell, nx, ny, packed)``: edge
        ends, for cell ``c = iy·nx + ix`` the edges ``items[start[c]:start[c+1]]``,
        the grid origin, cell size and shape, and per entry of ``items`` its edge's
        ends and box (:func:`_pack_edges`).
    """
    for g, grid in _cache:
        if g is target:
            return grid
    if isinstance(target, BeadUnion):
        ex0, ey0, ex1, ey1 = target.ex0, target.ey0, target.ex1, target.ey1
    else:
        parts = shapely.get_parts(shapely.boundary(target))
        coords, which = shapely.get_coordinates(parts, return_index=True)
        same = which[1:] == which[:-1]
        a = coords[:-1][same]
        b = coords[1:][same]
        ex0, ey0, ex1, ey1 = (np.ascontiguousarray(v)
                              for v in (a[:, 0], a[:, 1], b[:, 0], b[:, 1]))
    if len(ex0):
        x0, y0 = float(min(ex0.min(), ex1.min())), float(min(ey0.min(), ey1.min()))
        w = float(max(ex0.max(), ex1.max())) - x0
        hgt = float(max(ey0.max(), ey1.max())) - y0
    else:
        x0 = y0 = w = hgt = 0.0
    # ~1 mm cells (a footprint spans a few), at most ~250 k of them
    cell = max(1.0, math.sqrt(max(w * hgt, 1e-12) / 250_000.0))
    nx = int(w // cell) + 1
    ny = int(hgt // cell) + 1
    start, items = _bin_edges(ex0, ey0, ex1, ey1, x0, y0, cell, nx, ny)
    grid = (ex0, ey0, ex1, ey1, start, items, x0, y0, cell, nx, ny,
            _pack_edges(ex0, ey0, ex1, ey1, items))
    _cache.insert(0, (target, grid))
    del _cache[4:]
    return grid


@numba.njit(cache=True)
def _bin_edges(ex0, ey0, ex1, ey1, x0, y0, cell, nx, ny):  # pragma: no cover
    """CSR of the grid cells each edge's bounding box overlaps (two passes: count, fill)."""
    count = np.zeros(nx * ny + 1, np.int64)
    for pass_ in range(2):
        if pass_ == 1:
            for c in range(nx * ny):
                count[c + 1] += count[c]
            items = np.empty(count[nx * ny], np.int64)
            fill = count[:-1].copy()
        for e in range(len(ex0)):
            ix0 = _cell(min(ex0[e], ex1[e]), x0, cell, nx)
            ix1 = _cell(max(ex0[e], ex1[e]), x0, cell, nx)
            iy0 = _cell(min(ey0[e], ey1[e]), y0, cell, ny)
            iy1 = _cell(max(ey0[e], ey1[e]), y0, cell, ny)
            for iy in range(iy0, iy1 + 1):
                for ix in range(ix0, ix1 + 1):
                    c = iy * nx + ix
                    if pass_ == 0:
                        count[c + 1] += 1
                    else:
                        items[fill[c]] = e
                        fill[c] += 1
    return count, items


@numba.njit(cache=True)
def _pack_edges(ex0, ey0, ex1, ey1, items):  # pragma: no cover
    """Per entry of the grid's ``items``: its edge's x0, y0, x1, y1 and box (min x, max x,
    min y, max y), one row of 8 (one cache line) read in turn as a cell is scanned."""
    out = np.empty((len(items), 8))
    for q in range(len(items)):
        e = items[q]
        ax = ex0[e]
        ay = ey0[e]
        bx = ex1[e]
        by = ey1[e]
        out[q, 0] = ax
        out[q, 1] = ay
        out[q, 2] = bx
        out[q, 3] = by
        out[q, 4] = min(ax, bx)
        out[q, 5] = max(ax, bx)
        out[q, 6] = min(ay, by)
        out[q, 7] = max(ay, by)
    return out


@numba.njit(cache=True, _nrt=False)
def _clip(ax, ay, bx, by, cu, su, h, off, order):  # pragma: no cover
    """Fraction of [a, b] inside all half-planes ``cu·x + su·y ≤ h + off`` (Liang–Barsky).

    The half-planes are visited in ``order`` (the two sides and the two caps of
    the move first: most edges are cut off by one of them); min and max do not
    depend on the order, so neither does the result.
    """
    t0 = 0.0
    t1 = 1.0
    dx = bx - ax
    dy = by - ay
    for jj in range(len(order)):
        j = order[jj]
        p = cu[j] * dx + su[j] * dy
        q = h[j] + off - (cu[j] * ax + su[j] * ay)
        if p == 0.0:
            if q < 0.0:
                return -1.0
        elif p > 0.0:
            t = q / p
            if t < t1:
                t1 = t
        else:
            t = q / p
            if t > t0:
                t0 = t
        if t1 < t0:
            return -1.0
    return t1 - t0


@numba.njit(cache=True)
def _decide(rings, cu, su, h, ex0, ey0, ex1, ey1, start, items, x0, y0, cell, nx, ny, packed,
            todo, eps, order, out):  # pragma: no cover
    """Per ring of ``todo``: 1 inside, 0 not inside, -1 undecided (∂G within ``eps``).

    A hand-written kernel because the candidates are few (a grid cell or two of
    ∂G per footprint) and the test per edge is 64 multiply-adds: GEOS's general
    covers builds a noded graph of both boundaries for every footprint.
    """
    k = rings.shape[1] - 1
    found = np.zeros(1, np.int64)
    for m in range(len(todo)):
        i = todo[m]
        bx0 = rings[i, 0, 0]
        bx1 = bx0
        by0 = rings[i, 0, 1]
        by1 = by0
        for v in range(1, k):
            x = rings[i, v, 0]
            y = rings[i, v, 1]
            bx0 = min(bx0, x)
            bx1 = max(bx1, x)
            by0 = min(by0, y)
            by1 = max(by1, y)
        out[i] = _edges_state(cu[i], su[i], h[i], bx0 - eps, by0 - eps, bx1 + eps, by1 + eps,
                              start, items, x0, y0, cell, nx, ny, packed, eps, order, found)


@numba.njit(cache=True, _nrt=False)
def _edges_state(cu, su, h, bx0, by0, bx1, by1, start, items, x0, y0, cell, nx, ny, packed, eps,
                 order, found):  # pragma: no cover
    """One footprint of :func:`_decide`: 0 if ∂G enters it, -1 if ∂G grazes it, else 1.

    ``bx0``… is the ring's bounding box already grown by ``eps``; the edges are read
    from the grid's ``packed`` rows.
    """
    ix0 = _cell(bx0, x0, cell, nx)
    ix1 = _cell(bx1, x0, cell, nx)
    iy0 = _cell(by0, y0, cell, ny)
    iy1 = _cell(by1, y0, cell, ny)
    state = 1
    for iy in range(iy0, iy1 + 1):
        for ix in range(ix0, ix1 + 1):
            c = iy * nx + ix
            for q in range(start[c], start[c + 1]):
                if packed[q, 5] < bx0 or packed[q, 4] > bx1 or packed[q, 7] < by0 \
                        or packed[q, 6] > by1:
                    continue
                ax = packed[q, 0]
                ay = packed[q, 1]
                bx = packed[q, 2]
                by = packed[q, 3]
                if _clip(ax, ay, bx, by, cu, su, h, eps, order) < 0.0:
                    continue
                t = _clip(ax, ay, bx, by, cu, su, h, -eps, order)
                if t > 0.0 and t * math.hypot(bx - ax, by - ay) > eps:
                    found[0] = items[q]
                    return 0
                state = -1
    return state


@numba.njit(cache=True, _nrt=False)
def _inside(px, py, ex0, ey0, ex1, ey1, start, items, x0, y0, cell, nx, ny):  # pragma: no cover
    """Whether a point at least ~``EPS`` away from ∂G lies in G (parity of a ray's crossings).

    The ray runs along the point's grid row towards the nearer side of the grid;
    an edge listed in several cells of the row is counted in the first cell the
    ray reaches. Edges meet the ray under the half-open rule (one end strictly
    above), so a ray through a vertex counts it once; the crossing abscissa is
    only compared with the point's, which is far from the edge, so its rounding
    cannot flip the count.
    """
    iy = _cell(py, y0, cell, ny)
    ix = _cell(px, x0, cell, nx)
    right = nx - 1 - ix <= ix
    lo = ix if right else 0
    hi = nx - 1 if right else ix
    inside = False
    for c in range(iy * nx + lo, iy * nx + hi + 1):
        col = c - iy * nx
        for q in range(start[c], start[c + 1]):
            e = items[q]
            ax = ex0[e]
            ay = ey0[e]
            bx = ex1[e]
            by = ey1[e]
            if (ay > py) == (by > py):
                continue
            if right:
                first = max(ix, _cell(min(ax, bx), x0, cell, nx))
            else:
                first = min(ix, _cell(max(ax, bx), x0, cell, nx))
            if col != first:
                continue  # counted in another cell of the row
            xc = ax + (py - ay) * (bx - ax) / (by - ay)
            if (xc > px) if right else (xc < px):
                inside = not inside
    return inside


_DEEP = 1e-3
"""Relative margin of :func:`_deep_in_sweep`: orders above rounding, far below a footprint."""


@numba.njit(cache=True)
def _deep_in_sweep(ex0, ey0, ex1, ey1, sx, sy, a, b, cx, cy, rc, rs, c, s, sc):  # pragma: no cover
    """Whether the edge [e0, e1] (relative to the move's start) has a piece well inside the
    ellipse (semi-axes ``a``, ``b``, centre ``cx``, ``cy``, rotation ``rc``, ``rs``) at
    orientation ``c``, ``s`` scaled by ``sc`` swept from 0 to ``(sx, sy)``.

    In the frame where that ellipse is the unit disk the swept set is the set of points
    within 1 of a segment; an edge within ``1 - _DEEP`` of it has a piece longer than
    ``_DEEP / 2 · min(a, b) · sc`` (or the whole edge) more than that deep in the swept
    set, hence in every polygon around it, far beyond ``EPS``. A sufficient test of
    refusal, needing no half-plane: a rectangle holds the ellipse of its semi-axes.
    """
    m00, m01, m10, m11, qx, qy, tx, ty = _sweep_frame(sx, sy, a, b, cx, cy, rc, rs, c, s, sc)
    return _deep_in_frame(ex0, ey0, ex1, ey1, m00, m01, m10, m11, qx, qy, tx, ty)


@numba.njit(cache=True)
def _sweep_frame(sx, sy, a, b, cx, cy, rc, rs, c, s, sc):  # pragma: no cover
    """The frame of :func:`_deep_in_sweep`: its map ``M`` (row by row), the ellipse's centre
    ``q`` and the segment's end ``t`` in it (one per footprint, shared by the edges tried)."""
    # M = diag(1/a, 1/b) R(-rotation) R(-phi) / scale
    m00 = (rc * c - rs * s) / (a * sc)
    m01 = (rc * s + rs * c) / (a * sc)
    m10 = (-rs * c - rc * s) / (b * sc)
    m11 = (-rs * s + rc * c) / (b * sc)
    qx = (rc * cx + rs * cy) / a
    qy = (-rs * cx + rc * cy) / b
    tx = m00 * sx + m01 * sy + qx
    ty = m10 * sx + m11 * sy + qy
    return m00, m01, m10, m11, qx, qy, tx, ty


@numba.njit(cache=True)
def _deep_in_frame(ex0, ey0, ex1, ey1, m00, m01, m10, m11, qx, qy, tx, ty):  # pragma: no cover
    """:func:`_deep_in_sweep` given its :func:`_sweep_frame`."""
    ax = m00 * ex0 + m01 * ey0
    ay = m10 * ex0 + m11 * ey0
    bx = m00 * ex1 + m01 * ey1
    by = m10 * ex1 + m11 * ey1
    lim = 1.0 - _DEEP
    return _segments2(ax, ay, bx, by, qx, qy, tx, ty) < lim * lim


_NO_POLYGONS = (np.zeros(1, np.int64), np.zeros(0), np.zeros(0), np.zeros(0),
                np.zeros(2, np.int64), np.zeros(0, np.int64), 0.0, 0.0, 1.0, 1, 1,
                np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))


def locator(target: BaseGeometry | BeadUnion) -> tuple:
    """What :func:`first_fits` locates points with: a bead union's polygons, their grid
    and their beads (axis ends and radius), or nothing (a shapely target: parity of ∂G's
    crossings)."""
    if isinstance(target, BeadUnion):
        return (target.off, target.ux, target.uy, target.h, *target.grid, target.ax,
                target.ay, target.bx, target.by, target.rho)
    return _NO_POLYGONS


_AXIS = 1e-6
"""Margin (mm) of :func:`_near_axis`: far above the rounding of a bead polygon's half-planes."""


@numba.njit(cache=True, _nrt=False)
def _near_axis(px, py, start, items, x0, y0, cell, nx, ny, ax, ay, bx, by, rho):  # pragma: no cover
    """Whether the point is within ``rho - _AXIS`` of the axis of a bead listed in its cell.

    A sufficient test of :func:`~printability.motion.beadunion.in_polygons`: a bead
    polygon holds the points within ``rho`` of its axis (its half-planes are tangent to
    that capsule), and its box, by which it is listed in the cells, holds them too; at
    ``_AXIS`` inside, every half-plane holds them despite rounding. The points located
    are mostly on some move's axis, where the half-planes are many (a polygon's 2k) and
    this test is one distance.
    """
    c = _cell(py, y0, cell, ny) * nx + _cell(px, x0, cell, nx)
    for q in range(start[c], start[c + 1]):
        i = items[q]
        r = rho[i] - _AXIS
        if r > 0.0 and _point_segment2(px, py, ax[i], ay[i], bx[i], by[i]) < r * r:
            return True
    return False


@numba.njit(cache=True, _nrt=False)
def _locate(px, py, ex0, ey0, ex1, ey1, start, items, x0, y0, cell, nx, ny, loff, lux, luy, lh,
            lstart, litems, lx0, ly0, lcell, lnx, lny, lax, lay, lbx, lby,
            lrho):  # pragma: no cover
    """Whether a point at least ~``EPS`` from ∂G lies in G: in one of the polygons of a
    bead union when there are any (near a bead's axis first), else by the parity of ∂G's
    crossings."""
    if len(loff) > 1:
        if _near_axis(px, py, lstart, litems, lx0, ly0, lcell, lnx, lny, lax, lay, lbx, lby,
                      lrho):
            return True
        return in_polygons(px, py, loff, lux, luy, lh, lstart, litems, lx0, ly0, lcell, lnx,
                           lny)
    return _inside(px, py, ex0, ey0, ex1, ey1, start, items, x0, y0, cell, nx, ny)


@numba.njit(cache=True)
def first_fits(kind, pa, pb, pcx, pcy, prc, prs, p0, p1, cn, sn, scale, seg, gseg, c0, s0, c1, s1,
               k, gpos, gend, cb, sb, det, ex0, ey0, ex1, ey1, start, items, x0, y0, cell, nx,
               ny, packed, loff, lux, luy, lh, lstart, litems, lx0, ly0, lcell, lnx, lny, lax,
               lay, lbx, lby, lrho, eps, order, out_idx, out_state):  # pragma: no cover
    """Per group of candidates, the first whose swept footprint lies inside G.

    Candidate ``q`` sweeps the pieces (``kind`` 0 ellipse, 1 rectangle, with
    semi-axes ``pa``, ``pb``, centre ``pcx``, ``pcy``, rotation cos/sin
    ``prc``, ``prs``) along segment ``seg[q]`` (or ``gseg[g]`` for all the
    candidates of group ``g`` when ``gseg`` is non-empty: groups may then share
    candidates) (``p0``, ``p1``, normal ``cn``,
    ``sn``, ``scale`` if non-empty) at the orientation ``c0[q]``, ``s0[q]``
    (turning to ``c1``, ``s1`` with factor ``k`` when ``k`` is non-empty).
    Group ``g`` tries ``gpos[g] … gend[g] - 1`` in order and stops at the
    first that fits (``out_state`` 1, ``out_idx`` its index), at the first
    ∂G grazes (``out_state`` -1: shapely decides, the caller resumes after it)
    or finds none (``out_state`` 0, ``out_idx`` -1). ``loff`` … ``lny`` are
    :func:`locator`'s: points are located in a bead union's polygons.

    Each footprint gets the decision of :func:`covers_rings` on the ring of
    :func:`swept_kernel`: the half-planes are computed by the same code, the
    edge test is :func:`_decide`'s, and where no edge of ∂G comes within
    ``eps`` of the footprint (the only case where the footprint can lie inside)
    a point of it is located in G by :func:`_inside`, at least ``eps``
    from ∂G: the answer ``shapely.intersects_xy`` gives. Nothing is stored per
    footprint, which is what made one call per candidate expensive.

    Shortcuts, none of which changes an answer:

    * the four edges that last refused a footprint are tried first, before
      the footprint's box and cells (consecutive candidates are mostly refused
      by the same corner): an edge with a piece strictly inside the footprint
      is a refusal whichever edge the scan would have met first, and the scan
      finds such an edge (the piece lies in the footprint's box and cells).
      Without a turn they are first tested against the ellipses swept
      (:func:`_deep_in_sweep`, before any half-plane is computed: most
      candidates end there), then with :func:`_clip`;
    * the point located is the segment's start where it lies in every
      footprint (pieces centred on the nozzle, not mirrored by a negative
      scale: their half-planes hold it, the rounding included, since the
      offsets add a non-negative support to the segment's extent), located
      once per segment: all the points of a footprint that ∂G does not come
      within ``eps`` of are on the same side of ∂G.
    """
    d = len(cb)
    turning = len(k) > 0
    scaled = len(scale) > 0
    cu = np.empty(d)
    su = np.empty(d)
    w = np.empty(d)
    h = np.empty(d)
    centred = True  # every piece centred on the nozzle: the segment's start lies in it
    for p in range(len(kind)):
        if pcx[p] != 0.0 or pcy[p] != 0.0 or pa[p] < 0.0 or pb[p] < 0.0:
            centred = False
    mru = np.full(4, -1, np.int64)
    mru_len = np.zeros(4)  # their lengths
    found = np.zeros(1, np.int64)
    where = -1  # start point of the segment: -1 not located yet, 0 outside, 1 inside
    last = -1
    for g in range(len(gpos)):
        out_idx[g] = -1
        out_state[g] = 0
        for q in range(gpos[g], gend[g]):
            m = gseg[g] if len(gseg) else seg[q]
            if m != last:  # the candidates of a move share its directions
                _directions(cn[m], sn[m], cb, sb, p0[m, 0], p0[m, 1], p1[m, 0], p1[m, 1], cu,
                            su, w)
                last = m
                where = -1
            state = 1
            if not turning:
                # the edges that refused the last footprints, tested against the ellipse
                # swept (no half-plane needed): most candidates end here
                sc = scale[m] if scaled else 1.0
                for p in range(len(kind)):
                    if pa[p] <= 0.0 or pb[p] <= 0.0 or not sc * min(pa[p], pb[p]) >= 1e-3:
                        continue
                    sx = p1[m, 0] - p0[m, 0]
                    sy = p1[m, 1] - p0[m, 1]
                    m00, m01, m10, m11, qx, qy, tx, ty = _sweep_frame(
                        sx, sy, pa[p], pb[p], pcx[p], pcy[p], prc[p], prs[p], c0[q], s0[q], sc)
                    for r in range(len(mru)):
                        e = mru[r]
                        if e < 0:
                            break
                        if mru_len[r] < 1e-6:
                            continue
                        if _deep_in_frame(ex0[e] - p0[m, 0], ey0[e] - p0[m, 1],
                                          ex1[e] - p0[m, 0], ey1[e] - p0[m, 1], m00, m01, m10,
                                          m11, qx, qy, tx, ty):
                            _to_front(mru, mru_len, r, e, mru_len[r])
                            state = 0
                            break
                    if state == 0:
                        break
                if state == 0:
                    continue
            for p in range(len(kind)):
                _offsets(kind[p], pa[p], pb[p], pcx[p], pcy[p], prc[p], prs[p], c0[q], s0[q],
                         c1[q] if turning else 0.0, s1[q] if turning else 0.0,
                         k[q] if turning else 1.0, turning, scale[m] if scaled else 1.0, scaled,
                         cu, su, w, h)
                refused = False
                for r in range(len(mru)):
                    e = mru[r]
                    if e < 0:
                        break
                    ax = ex0[e]
                    ay = ey0[e]
                    bx = ex1[e]
                    by = ey1[e]
                    # only the refusal test: the shortcut never accepts, so whether
                    # the edge meets the footprint grown by eps is left to the scan
                    t = _clip(ax, ay, bx, by, cu, su, h, -eps, order)
                    if t > 0.0 and t * mru_len[r] > eps:
                        _to_front(mru, mru_len, r, e, mru_len[r])
                        refused = True
                        break
                if refused:
                    state = 0
                    break
                # the bounding box of the ring's vertices as swept_kernel computes them
                # ((numerator) / det each): dividing by det > 0 keeps the order of the
                # rounded values, so the extreme numerators give the extreme vertices
                nx0 = h[0] * su[1] - h[1] * su[0]
                ny0 = cu[0] * h[1] - cu[1] * h[0]
                mx0 = nx0
                mx1 = nx0
                my0 = ny0
                my1 = ny0
                for j in range(1, d):
                    jn = j + 1 if j + 1 < d else 0
                    x = h[j] * su[jn] - h[jn] * su[j]
                    y = cu[j] * h[jn] - cu[jn] * h[j]
                    mx0 = min(mx0, x)
                    mx1 = max(mx1, x)
                    my0 = min(my0, y)
                    my1 = max(my1, y)
                st = _edges_state(cu, su, h, mx0 / det - eps, my0 / det - eps, mx1 / det + eps,
                                  my1 / det + eps, start, items, x0, y0, cell, nx, ny, packed,
                                  eps, order, found)
                if st == 0:
                    e = found[0]
                    _to_front(mru, mru_len, len(mru) - 1, e,
                              math.hypot(ex1[e] - ex0[e], ey1[e] - ey0[e]))
                if st == 1:
                    if centred and not (scaled and scale[m] < 0.0):
                        if where < 0:
                            where = 1 if _locate(p0[m, 0], p0[m, 1], ex0, ey0, ex1, ey1,
                                                 start, items, x0, y0, cell, nx, ny, loff, lux,
                                                 luy, lh, lstart, litems, lx0, ly0, lcell, lnx,
                                                 lny, lax, lay, lbx, lby, lrho) else 0
                        inside = where == 1
                    else:
                        inside = _locate(nx0 / det, ny0 / det, ex0, ey0, ex1, ey1, start,
                                         items, x0, y0, cell, nx, ny, loff, lux, luy, lh, lstart,
                                         litems, lx0, ly0, lcell, lnx, lny, lax, lay, lbx,
                                         lby, lrho)
                    if not inside:
                        st = 0
                if st == 0:
                    state = 0
                    break
                if st == -1:
                    state = -1  # still 0 if another piece pokes out
            if state != 0:
                out_idx[g] = q
                out_state[g] = state
                break


@numba.njit(cache=True, _nrt=False)
def _to_front(mru, mru_len, r, e, length):  # pragma: no cover
    """Move edge ``e`` (of length ``length``) to the front of the most recently used edges,
    from slot ``r`` (or the last one: the edge drops out)."""
    for rr in range(r, 0, -1):
        mru[rr] = mru[rr - 1]
        mru_len[rr] = mru_len[rr - 1]
    mru[0] = e
    mru_len[0] = length


@functools.lru_cache(maxsize=8)
def _order(d: int) -> np.ndarray:
    """Every direction once, coarse to fine: 0 and d/2 (normal to the move), d/4 and 3d/4
    (along it), then the diagonals, then halfway between those…

    An edge outside the footprint is usually cut off by a half-plane of the coarsest
    polygon around it: visiting the directions so, it leaves after two or three instead
    of a third of them on average when they are taken in turn.
    """
    out = [0]
    k = d
    while k > 1:
        k //= 2
        out += [j for j in range(k, d, 2 * k) if j % k == 0]
    head = [0, d // 2, d // 4, (3 * d) // 4]
    order = np.array(list(dict.fromkeys([*head, *out, *range(d)])), dtype=np.int64)
    order.setflags(write=False)
    return order


def covers_rings(target: BaseGeometry, rings: np.ndarray, cu: np.ndarray, su: np.ndarray,
                 h: np.ndarray) -> np.ndarray:
    """``shapely.covers(target, shapely.polygons(rings))``, deciding the clear cases exactly.

    Parameters
    ----------
    target
        G (prepared).
    rings
        (n, k + 1, 2) closed rings of convex footprints.
    cu, su, h
        (n, k) their half-planes ``cu·x + su·y ≤ h`` (the ring's vertices are
        where adjacent boundary lines cross).

    Returns
    -------
    bool ndarray, shape (n,)
    """
    n = len(rings)
    out = np.zeros(n, dtype=bool)
    if n == 0:
        return out
    # a vertex strictly outside G: not inside; otherwise that vertex is a point of G
    inside = contains_xy(target, rings[:, 0, 0], rings[:, 0, 1])
    todo = np.flatnonzero(inside)
    if todo.size == 0:
        return out
    state = np.full(n, 0, np.int8)
    grid = boundary_grid(target)
    _decide(np.ascontiguousarray(rings), np.ascontiguousarray(cu), np.ascontiguousarray(su),
            np.ascontiguousarray(h), *grid, todo, EPS, _order(h.shape[1]), state)
    out[state == 1] = True
    rest = np.flatnonzero(state == -1)
    if rest.size:
        out[rest] = covers(target, shapely.polygons(rings[rest]))
    return out


def contains_xy(target: BaseGeometry | BeadUnion, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``shapely.intersects_xy(target, x, y)``, for a shapely target or a bead union."""
    if isinstance(target, BeadUnion):
        return union_contains_xy(target, x, y)
    return shapely.intersects_xy(target, x, y)


def covers(target: BaseGeometry | BeadUnion, polygons: np.ndarray) -> np.ndarray:
    """``shapely.covers(target, polygons)``, for a shapely target or a bead union."""
    if isinstance(target, BeadUnion):
        return union_covers(target, polygons)
    return shapely.covers(target, polygons)


@numba.njit(cache=True, _nrt=False)
def _directions(cn, sn, cb, sb, p0x, p0y, p1x, p1y, cu, su, w):  # pragma: no cover
    """Directions ``cu``, ``su`` of a move's half-planes and the move's extent ``w`` along them.

    Independent of the orientation: the candidates of one move share them.
    """
    for j in range(len(cb)):
        u = cn * cb[j] - sn * sb[j]
        v = sn * cb[j] + cn * sb[j]
        cu[j] = u
        su[j] = v
        w[j] = max(u * p0x + v * p0y, u * p1x + v * p1y)


@numba.njit(cache=True, _nrt=False)
def _offsets(kind, a, b, cx, cy, rc, rs, c0, s0, c1, s1, k, turning, scale, scaled, cu, su, w,
             h):  # pragma: no cover
    """Offsets ``h`` of the half-planes of an ellipse (kind 0) or rectangle (kind 1) swept.

    The swept_kernel's arithmetic, shared with the fused tests so that their
    half-planes are those of the ring, to the last bit.
    """
    for j in range(len(cu)):
        u = cu[j]
        v = su[j]
        hv = 0.0
        for end in range(2 if turning else 1):
            c = c0 if end == 0 else c1
            s = s0 if end == 0 else s1
            ux = c * u + s * v  # u in the nozzle frame: R(-phi) u
            uy = -s * u + c * v
            base = ux * cx + uy * cy
            vx = rc * ux + rs * uy  # u in the orifice's own axes
            vy = -rs * ux + rc * uy
            if kind == 0:
                hh = base + math.sqrt((a * vx) ** 2 + (b * vy) ** 2)
            else:
                hh = base + a * abs(vx) + b * abs(vy)
            hv = hh if end == 0 else max(hv, hh)
        if turning:
            hv = hv * k
        if scaled:
            hv = hv * scale
        h[j] = hv + w[j]


@numba.njit(cache=True)
def swept_kernel(kind, a, b, cx, cy, rc, rs, p0, p1, cn, sn, cb, sb, c0, s0, c1, s1, k, scale,
                 det, cu, su, h, ring):  # pragma: no cover
    """Half-plane offsets ``h`` and ring of an ellipse (kind 0) or rectangle (kind 1) swept.

    The same arithmetic, in the same order, as the numpy path of
    :func:`printability.motion.footprints.swept_rings` (so the same rings to
    the last bit), fused into one pass: numpy makes a dozen (n, 64)
    temporaries per call, which cost more than the arithmetic. ``c1``/``s1``
    (the end orientation, turning moves) are used when ``k`` is non-empty,
    ``scale`` when non-empty; the directions ``cu``, ``su`` are filled from
    the move's normal (``cn``, ``sn``) and the base directions (``cb``, ``sb``).
    """
    n, d = cu.shape
    turning = len(k) > 0
    scaled = len(scale) > 0
    w = np.empty(d)
    for i in range(n):
        _directions(cn[i], sn[i], cb, sb, p0[i, 0], p0[i, 1], p1[i, 0], p1[i, 1], cu[i], su[i],
                    w)
        _offsets(kind, a, b, cx, cy, rc, rs, c0[i], s0[i], c1[i] if turning else 0.0,
                 s1[i] if turning else 0.0, k[i] if turning else 1.0, turning,
                 scale[i] if scaled else 1.0, scaled, cu[i], su[i], w, h[i])
        for j in range(d):
            jn = j + 1 if j + 1 < d else 0
            ring[i, j, 0] = (h[i, j] * su[i, jn] - h[i, jn] * su[i, j]) / det
            ring[i, j, 1] = (cu[i, j] * h[i, jn] - cu[i, jn] * h[i, j]) / det
        ring[i, d, 0] = ring[i, 0, 0]
        ring[i, d, 1] = ring[i, 0, 1]

"""The fused planner kernel: per group of candidates, the first that fits inside G.

:func:`first_fits` sweeps the pieces with the arithmetic of
:mod:`printability.motion._sweep`, tests the edges of ∂G near each footprint as
:mod:`printability.motion._covers` does and locates a point of it with
:mod:`printability.motion._point_location`, storing nothing per footprint;
:func:`_to_front` keeps the few edges that last refused a footprint, tried
first.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.motion._covers import _clip, _edges_state
from printability.motion._point_location import _locate
from printability.motion._sweep import (
    _deep_in_frame,
    _directions,
    _move_normal,
    _offsets,
    _sweep_frame,
)

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["first_fits"]


@numba.njit(cache=True, nogil=True)
def first_fits(kind, pa, pb, pcx, pcy, prc, prs, p0, p1, scale, seg, gseg, c0, s0, c1, s1,
               k, gpos, gend, cb, sb, det, ex0, ey0, ex1, ey1, start, items, x0, y0, cell, nx,
               ny, packed, loff, lux, luy, lh, lstart, litems, lx0, ly0, lcell, lnx, lny, lax,
               lay, lbx, lby, lrho, eps, order, out_idx, out_state):  # pragma: no cover
    """Per group of candidates, the first whose swept footprint lies inside G.

    Candidate ``q`` sweeps the pieces (``kind`` 0 ellipse, 1 rectangle, with
    semi-axes ``pa``, ``pb``, centre ``pcx``, ``pcy``, rotation cos/sin
    ``prc``, ``prs``) along segment ``seg[q]`` (or ``gseg[g]`` for all the
    candidates of group ``g`` when ``gseg`` is non-empty: groups may then share
    candidates) (``p0``, ``p1``, ``scale`` if non-empty; the normal of
    :func:`_move_normal`) at the orientation ``c0[q]``, ``s0[q]``
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
      candidates end there), then with :func:`_clip`; a segment's directions are found
      only once one of its candidates gets past that test;
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
    directed = False  # cu, su, w are the current segment's
    last = -1
    for g in range(len(gpos)):
        out_idx[g] = -1
        out_state[g] = 0
        for q in range(gpos[g], gend[g]):
            m = gseg[g] if len(gseg) else seg[q]
            if m != last:  # the candidates of a move share its directions
                last = m
                where = -1
                directed = False
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
            if not directed:  # (found only now: the shortcut above ends most candidates)
                cn, sn = _move_normal(p0[m, 0], p0[m, 1], p1[m, 0], p1[m, 1])
                _directions(cn, sn, cb, sb, p0[m, 0], p0[m, 1], p1[m, 0], p1[m, 1], cu,
                            su, w)
                directed = True
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
                              math.sqrt((ex1[e] - ex0[e]) ** 2 + (ey1[e] - ey0[e]) ** 2))
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

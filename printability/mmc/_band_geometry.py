"""Plane geometry kernels of the band settling (:mod:`printability.mmc._band`).

Small compiled primitives shared by the slides, the lower bound and the quadtree: distances
between points, segments, boxes and convex polygons, clipping a convex polygon to a
half-plane, and the tests of a point or a convex polygon against the certified pieces
(parallelograms ``quads`` and ellipses ``caps``, laid out as in
:class:`printability.mmc._band.BandPieces`). Convex polygons are given as coordinate arrays
and a vertex count, counter-clockwise.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = [
    "clip_left",
    "disjoint_cap",
    "disjoint_quad",
    "dist_point_segment",
    "dist_seg_box",
    "in_cap",
    "in_quad",
    "inside_convex",
    "orient",
    "parity_flips",
    "poly_dist",
    "polygon_area",
    "seg_meets_box",
    "seg_seg_dist",
]

_INF = np.inf


@nb.njit(cache=True)
def dist_point_segment(px, py, ax, ay, bx, by):  # pragma: no cover - numba
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



@nb.njit(cache=True, inline="always")
def orient(ax, ay, bx, by, cx, cy):  # pragma: no cover - numba
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@nb.njit(cache=True)
def seg_meets_box(ax, ay, bx, by, x0, y0, x1, y1):  # pragma: no cover - numba
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
def clip_left(px, py, n, ax, ay, bx, by, ox, oy):  # pragma: no cover - numba
    """Clip the convex polygon (px, py)[:n] to the left of the line a→b; result in (ox, oy)."""
    m = 0
    for k in range(n):
        cx, cy = px[k], py[k]
        dx, dy = px[(k + 1) % n], py[(k + 1) % n]
        sc = orient(ax, ay, bx, by, cx, cy)
        sd = orient(ax, ay, bx, by, dx, dy)
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
def polygon_area(px, py, n):  # pragma: no cover - numba
    s = 0.0
    for k in range(n):
        s += px[k] * py[(k + 1) % n] - px[(k + 1) % n] * py[k]
    return 0.5 * s


@nb.njit(cache=True)
def dist_seg_box(ax, ay, bx, by, x0, y0, x1, y1):  # pragma: no cover - numba
    """Distance from segment ab to the closed box [x0, x1] × [y0, y1]."""
    if seg_meets_box(ax, ay, bx, by, x0, y0, x1, y1):
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
        best = min(best, dist_point_segment(cx, cy, ax, ay, bx, by))
    return best



@nb.njit(cache=True)
def seg_seg_dist(ax, ay, bx, by, cx, cy, dx, dy):  # pragma: no cover - numba
    o1 = orient(ax, ay, bx, by, cx, cy)
    o2 = orient(ax, ay, bx, by, dx, dy)
    o3 = orient(cx, cy, dx, dy, ax, ay)
    o4 = orient(cx, cy, dx, dy, bx, by)
    if ((o1 > 0.0) != (o2 > 0.0)) and ((o3 > 0.0) != (o4 > 0.0)):
        return 0.0
    return min(dist_point_segment(ax, ay, cx, cy, dx, dy),
               dist_point_segment(bx, by, cx, cy, dx, dy),
               dist_point_segment(cx, cy, ax, ay, bx, by),
               dist_point_segment(dx, dy, ax, ay, bx, by))


@nb.njit(cache=True)
def inside_convex(px, py, n, x, y):  # pragma: no cover - numba
    """Whether (x, y) lies in the closed convex polygon (px, py)[:n] (counter-clockwise)."""
    for k in range(n):
        k2 = (k + 1) % n
        if orient(px[k], py[k], px[k2], py[k2], x, y) < 0.0:
            return False
    return True


@nb.njit(cache=True)
def poly_dist(ax, ay, na, bx, by, nb_):  # pragma: no cover - numba
    """Distance between two convex polygons (counter-clockwise), 0 when they meet."""
    for k in range(na):
        if inside_convex(bx, by, nb_, ax[k], ay[k]):
            return 0.0
    for k in range(nb_):
        if inside_convex(ax, ay, na, bx[k], by[k]):
            return 0.0
    best = _INF
    for k in range(na):
        k2 = (k + 1) % na
        for q in range(nb_):
            q2 = (q + 1) % nb_
            best = min(best, seg_seg_dist(ax[k], ay[k], ax[k2], ay[k2],
                                           bx[q], by[q], bx[q2], by[q2]))
    return best



@nb.njit(cache=True)
def in_quad(quads, q, x, y, tau, base_tol):  # pragma: no cover - numba
    """Point strictly inside quad q (≥ tau from sides 1–3; side 0, the base, down to
    −base_tol)."""
    for s in range(4):
        ax, ay = quads[q, 2 * s], quads[q, 2 * s + 1]
        bx, by = quads[q, (2 * s + 2) % 8], quads[q, (2 * s + 3) % 8]
        ln = math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)
        if ln == 0.0:
            return False
        d = orient(ax, ay, bx, by, x, y) / ln
        if s == 0:
            if d < -base_tol:
                return False
        elif d < tau:
            return False
    return True


@nb.njit(cache=True, inline="always")
def in_cap(caps, c, x, y):  # pragma: no cover - numba
    dx = x - caps[c, 0]
    dy = y - caps[c, 1]
    u = caps[c, 2] * dx + caps[c, 3] * dy
    v = caps[c, 4] * dx + caps[c, 5] * dy
    return u * u + v * v <= 1.0 - 1e-9


@nb.njit(cache=True)
def disjoint_quad(quads, q, px, py, n):  # pragma: no cover - numba
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
def disjoint_cap(caps, c, px, py, n):  # pragma: no cover - numba
    """Whether the convex polygon misses the ellipse (distance > 1 in its unit-disk frame)."""
    inside = True
    best = _INF
    for k in range(n):
        ax = caps[c, 2] * (px[k] - caps[c, 0]) + caps[c, 3] * (py[k] - caps[c, 1])
        ay = caps[c, 4] * (px[k] - caps[c, 0]) + caps[c, 5] * (py[k] - caps[c, 1])
        k2 = (k + 1) % n
        bx = caps[c, 2] * (px[k2] - caps[c, 0]) + caps[c, 3] * (py[k2] - caps[c, 1])
        by = caps[c, 4] * (px[k2] - caps[c, 0]) + caps[c, 5] * (py[k2] - caps[c, 1])
        if orient(ax, ay, bx, by, 0.0, 0.0) < 0.0:
            inside = False
        best = min(best, dist_point_segment(0.0, 0.0, ax, ay, bx, by))
    if inside:
        return False
    return best > 1.0


@nb.njit(cache=True)
def parity_flips(edges, elist, ax, ay, bx, by):  # pragma: no cover - numba
    """Crossings of segment a→b with the listed edges; −1 when a position is degenerate."""
    flips = 0
    for t in range(elist.shape[0]):
        e = elist[t]
        px, py, qx, qy = edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3]
        o1 = orient(ax, ay, bx, by, px, py)
        o2 = orient(ax, ay, bx, by, qx, qy)
        o3 = orient(px, py, qx, qy, ax, ay)
        o4 = orient(px, py, qx, qy, bx, by)
        if o1 == 0.0 or o2 == 0.0 or o3 == 0.0 or o4 == 0.0:
            # touching or collinear: only degenerate when the boxes overlap
            if (min(px, qx) <= max(ax, bx) and min(ax, bx) <= max(px, qx)
                    and min(py, qy) <= max(ay, by) and min(ay, by) <= max(py, qy)):
                return -1
            continue
        if (o1 > 0.0) != (o2 > 0.0) and (o3 > 0.0) != (o4 > 0.0):
            flips += 1
    return flips

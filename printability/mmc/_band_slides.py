"""Slide and pivot kernels of the band settling (:mod:`printability.mmc._band`).

In the mapped plane (the footprint a unit disk), :func:`slide_intervals` finds the free
slide intervals of every edge (the centres at 1 + ε from it whose disks of radius 1 + ε/2
meet no neighbouring edge) and :func:`pivot_centres` the feasible pivot centres about
reflex vertices; :mod:`printability.mmc._band` proves why they are placements and turns
them into certified pieces.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.mmc._band_geometry import dist_point_segment

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["blocked_interval", "pivot_centres", "slide_intervals"]

_INF = np.inf


@nb.njit(cache=True, inline="always")
def blocked_interval(p0x, p0y, tx, ty, nx_, ny_, g0x, g0y, g1x, g1y, r
                     ):  # pragma: no cover - numba
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
    # hypot, not sqrt(l2): a segment ~1e-162 long has a subnormal l2 whose square root is
    # off by a percent, which would scale the normal and widen the band.  Below 1e-100 mm the
    # segment is its two endpoint disks (the sausage's middle is narrower than 1e-200 mm).
    lg = math.hypot(vx, vy)
    if lg > 1e-100:
        l2 = lg * lg
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
            lo, hi = blocked_interval(p0x, p0y, tx, ty, nx_, ny_, g0x, g0y, g1x, g1y, r)
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
                    if dist_point_segment(cx, cy, me[g, 0], me[g, 1], me[g, 2], me[g, 3]) < r:
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

"""The bead polygons of :mod:`printability.planning.beadunion`: half-planes, corners and boxes.

Each bead of radius r along [a, b] becomes C = [a, b] ⊕ Q, Q the regular 2k-gon about the
circle of radius ρ with its corners at (m + ½)·π/k for every bead (see
:mod:`printability.planning.beadunion` for why, and for the bounds this keeps). Polygon i has
2k + 2 half-planes ``ux·x + uy·y ≤ h``, clockwise from its left side (normal l, the
segment's direction turned by +90°): the left side, the k edges of the cap at b (Q's normals
from the one just clockwise of l, ``phase`` radians from it, in steps of π/k), the right
side, the k edges of the cap at a; corner j ends edge j. :func:`cell_grid` bins the polygons'
boxes for the neighbour searches and point location.

Coordinates and lengths in mm, angles in radians.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.planning._kernels import bin_boxes as _bin_boxes
from printability.planning.records import CellGrid

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["bead_polygons", "cell_grid"]


@numba.njit(cache=True, nogil=True)
def bead_polygons(ax, ay, bx, by, rho, rmax):  # pragma: no cover
    """Half-planes, corners and boxes of every bead polygon, its edges per half turn and
    the phase of its cap planes (see the module docs)."""
    n = len(ax)
    k = np.empty(n, np.int64)
    off = np.zeros(n + 1, np.int64)
    kmax = 2
    for i in range(n):
        # the fewest edges per half turn whose corners, at rho / cos(pi / 2k), stay in rmax
        k[i] = max(2, math.ceil(math.pi / (2.0 * math.acos(rho[i] / rmax[i]))))
        kmax = max(kmax, k[i])
        off[i + 1] = off[i] + 2 * k[i] + 2
    # cos/sin of m·π/k (edge normals) and (m + ½)·π/k (corners), once per k in use
    used = np.zeros(kmax + 1, np.bool_)
    for i in range(n):
        used[k[i]] = True
    nc = np.zeros((kmax + 1, 2 * kmax))
    ns = np.zeros((kmax + 1, 2 * kmax))
    vc = np.zeros((kmax + 1, 2 * kmax))
    vs = np.zeros((kmax + 1, 2 * kmax))
    for kk in range(2, kmax + 1):
        if used[kk]:
            for m in range(2 * kk):
                nc[kk, m] = math.cos(m * math.pi / kk)
                ns[kk, m] = math.sin(m * math.pi / kk)
                vc[kk, m] = math.cos((m + 0.5) * math.pi / kk)
                vs[kk, m] = math.sin((m + 0.5) * math.pi / kk)
    total = off[n]
    ux = np.empty(total)
    uy = np.empty(total)
    h = np.empty(total)
    vx = np.empty(total)
    vy = np.empty(total)
    box = np.empty((n, 4))
    phase = np.empty(n)
    for i in range(n):
        dx = bx[i] - ax[i]
        dy = by[i] - ay[i]
        length = math.hypot(dx, dy)
        tx, ty = (dx / length, dy / length) if length > 0 else (1.0, 0.0)
        lx = -ty  # left normal
        ly = tx
        ki = k[i]
        two = 2 * ki
        step = math.pi / ki
        big = rho[i] / vc[ki, 0]
        # the corner of Q nearest l: corner ml, at (ml + ½)·step, lies within half a step of
        # l's angle; the cap at b runs clockwise from it to the opposite corner ml - k
        psi = math.atan2(ly, lx)
        if psi < 0.0:
            psi += 2.0 * math.pi
        ml = min(max(math.floor(psi / step), 0), two - 1)
        phase[i] = psi - ml * step
        q = off[i]
        for side in range(2):
            sgn = 1.0 if side == 0 else -1.0
            su0 = sgn * lx
            su1 = sgn * ly
            cm = ml if side == 0 else (ml + ki) % two  # Q's corner extreme along ±l
            # the side touches the extreme corner (its neighbours too, should rounding tie
            # them with it)
            hq = -1e300
            for dm in range(-1, 2):
                mm = (cm + dm) % two
                hq = max(hq, big * (su0 * vc[ki, mm] + su1 * vs[ki, mm]))
            j = q + side * (ki + 1)
            ux[j] = su0
            uy[j] = su1
            h[j] = hq + max(su0 * ax[i] + su1 * ay[i], su0 * bx[i] + su1 * by[i])
            # corner j ends edge j: the side ends at the extreme corner, on the cap it
            # runs to (b after the left side, a after the right one)
            cx = bx[i] if side == 0 else ax[i]
            cy = by[i] if side == 0 else ay[i]
            vx[j] = cx + big * vc[ki, cm]
            vy[j] = cy + big * vs[ki, cm]
            m = cm  # the normal between corners m and e = m - 1 (mod 2k: no division)
            for r in range(ki):
                e = m - 1 if m > 0 else two - 1
                j = q + side * (ki + 1) + 1 + r
                u0 = nc[ki, m]
                u1 = ns[ki, m]
                ux[j] = u0
                uy[j] = u1
                h[j] = max(u0 * ax[i] + u1 * ay[i], u0 * bx[i] + u1 * by[i]) + rho[i]
                vx[j] = cx + big * vc[ki, e]
                vy[j] = cy + big * vs[ki, e]
                m = e
        box[i, 0] = min(ax[i], bx[i]) - big
        box[i, 1] = min(ay[i], by[i]) - big
        box[i, 2] = max(ax[i], bx[i]) + big
        box[i, 3] = max(ay[i], by[i]) + big
    return off, ux, uy, h, vx, vy, box, k, phase


def cell_grid(box: np.ndarray) -> CellGrid:
    """Uniform grid over the polygons' boxes, about one polygon per cell (CSR)."""
    x0, y0 = float(box[:, 0].min()), float(box[:, 1].min())
    w = float(box[:, 2].max()) - x0
    hgt = float(box[:, 3].max()) - y0
    cell = max(0.25, math.sqrt(max(w * hgt, 1e-12) / len(box)))
    nx = int(w // cell) + 1
    ny = int(hgt // cell) + 1
    start, items = _bin_boxes(box[:, 0], box[:, 1], box[:, 2], box[:, 3], x0, y0, cell, nx, ny)
    return CellGrid(start, items, x0, y0, cell, nx, ny)

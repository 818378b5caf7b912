"""A layer target grown by the tolerance, as the union of convex bead polygons.

The post-processor tests every swept footprint against G ⊕ τ, where G is the
union of the layer's beads (capsules: the points within w/2 of a move, see
:mod:`printability.sources.gcode`). Building G with GEOS (a buffer per chain,
``union_all``, then a buffer by τ) costs more than the slicer's own slicing
on busy parts, yet the footprint test (:mod:`printability.motion.fastfit`)
only needs the edges of the boundary and a point-in-region test. This module
computes exactly those, without an overlay.

The region
----------
Each bead of radius r along the segment [a, b] becomes the convex polygon

    C = [a, b] ⊕ Q,

with Q a regular 2k-gon circumscribed about the circle of radius
ρ = r + sτ (s = :data:`SIDE`), its corners at the angles (m + ½)·π/k, m = 0 … 2k − 1,
the same for every bead: the caps of two chords that meet at a point of a path
(equal widths) are then the same corners, and their union's boundary there is one
arc of Q, not the two polygons' corners poking through each other's edges in turn (on
the calibration cube 97 000 boundary pieces, 69 000 of them under 10 µm, against
40 000, 4 000; every footprint test reads fewer). C's straight sides, parallel to
the segment through Q's extreme corners, stand between ρ and ρ / cos(π/2k) from the
path. k is the smallest count whose corners stay within r·c + τ of the segment,
where c is the inner factor of the GEOS reconstruction (:data:`INNER`, quad_segs 32).
Hence, with G₃₂ the polygonal G the rest of the project builds,

    capsule(r + sτ) ⊆ C ⊆ capsule(r·c + τ) ⊆ G₃₂ ⊕ τ,

and the union G' of the C's lies between G ⊕ sτ and G₃₂ ⊕ τ: every
footprint accepted against G' lies inside the target within the tolerance,
and a footprint laying exactly the planned width (half-width r) clears the
sides by at least sτ. The rest of the tolerance, (1 − s)τ less the reference polygon's
own shortfall r(1 − c), is the room the corners have: the smaller s, the
fewer corners (k) and the faster the boundary and every footprint test on it.

Polygon i has 2k + 2 half-planes, clockwise from its left side (normal l, the
segment's direction turned by +90°): the left side, the k edges of the cap at b (the
normals of Q from the one just clockwise of l, ``phase`` radians from it, in steps of
π/k), the right side, the k edges of the cap at a.

The boundary
------------
∂G' is made of the pieces of the polygons' edges that no other polygon
covers. An edge of C_i is clipped against each overlapping C_j (Liang–Barsky
on C_j's half-planes) and the covered intervals are removed, with one tie
rule so that coincident edges facing the same way (a move printed twice, the
sides of a path's consecutive chords) leave one copy: C_j with j < i removes
what lies in C_j grown by ε, C_j with j > i what lies in C_j shrunk by ε
(ε = 1e-9 mm); each half-plane of C_j is moved out by a further ε(1 − cos φ),
φ its angle to the edge's outward normal, so that an edge lying on an
opposite edge of C_j (two beads that just touch) is covered by ε and leaves
no copy. The margin keeps every decision about edges that run along each
other well away from rounding; in exchange two pieces meeting where edges
cross at an angle θ may miss each other by up to about 2ε/sin θ. Any point
of ∂G' is therefore within that of a kept piece, and a footprint that meets
no kept piece leaves G' by at most about 2ε, far inside the tolerance. Points are located in G'
by the polygons themselves (:func:`union_contains_xy`), never by counting
boundary crossings, so those gaps cannot mislead it.

Each clip evaluates only C_j's two sides and the cap planes that face the edge's ends
(:func:`_window`, :func:`_clip_windows`): a plane that holds both ends by a margin cannot
move the interval, so the result is the full loop's to the bit, at about a tenth of the
planes. An edge starts where the last one ended, so :func:`_boundary` keeps each
neighbour's window of that corner (a third of the windows are found so), and the two
ends' windows are evaluated as one arc where they overlap (:func:`_clip_windows`).

Conventions: coordinates and lengths in mm; edges as four arrays
(x0, y0, x1, y1). Cost: linear in the beads times the number of beads
overlapping each (a uniform grid finds them): on Benchy (76 000 beads in 240
layers) about 0.7 s, against 3.9 s for GEOS's union and buffer of the same beads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import shapely

from printability._parallel import shared_out
from printability.errors import InputError
from printability.motion._kernels import bin_boxes as _bin_boxes
from printability.motion._kernels import cell_of as _cell
from printability.motion._kernels import clip_step as _clip_step
from printability.motion._kernels import point_segment2 as _point_segment2
from printability.motion._kernels import segment_offset as _segment_offset
from printability.motion._kernels import segments2 as _segments2

__all__ = ["INNER", "SIDE", "BeadUnion", "bead_union", "in_polygons", "union_contains_xy",
           "union_covers"]

INNER = math.cos(math.pi / 128)
"""Inner factor of a circle polygonised with 32 segments per quarter (GEOS quad_segs=32):
the polygon holds the disc of radius r·INNER."""

SIDE = 0.35
"""The polygons' straight sides stand s·τ out of their bead (see the module docs). Measured
on eight sliced files with the ellipse 0.8 × 0.3 (τ = 0.95 µm): 0.35 instead of an even
0.5 has 23 corners per half turn instead of 27 and cuts the post-processor's CPU by 4-6 %
on the cube, 10-17 % on Tolerance and Benchy; the dropped length moves by -0.3 to +0.4 % on
four of five files and by +6 % on Cura's sample (0.03 % of its extruded length); 0.25 and
0.15 gain little more and drop more there."""

_EPS = 1e-9
_PARALLEL_MIN = 1000
"""Fewest beads :func:`bead_union` gives a thread of its own."""


@dataclass(frozen=True, eq=False)
class BeadUnion:
    """G' for one layer: the bead polygons, their grid, and the edges of the union's boundary.

    Compared by identity (caches key on it). Arrays are read-only by convention.

    Attributes
    ----------
    ax, ay, bx, by, rho : ndarray
        Each bead's segment and side offset ρ (mm).
    off : ndarray
        Polygon i has half-planes ``ux·x + uy·y ≤ h`` and corners ``vx, vy`` at
        ``off[i]:off[i + 1]`` (corner j ends edge j).
    ux, uy, h, vx, vy : ndarray
        Half-planes and corners of every polygon.
    box : ndarray
        (n, 4) bounding box of each polygon.
    k, phase : ndarray
        Each polygon's edges per half turn and the angle (radians, clockwise) from its
        left side's normal to the next plane's (the module docs).
    grid : tuple
        ``(start, items, x0, y0, cell, nx, ny)``: the polygons whose box meets
        cell ``iy·nx + ix``.
    ex0, ey0, ex1, ey1 : ndarray
        Edges of ∂G'.
    beyond : ndarray
        How far each edge's line stands beyond ρ from its bead's path, mm (0 on the
        caps; on the sides, Q's extreme corner's excess, below ρ(1/cos(π/2k) − 1)).
    area : float
        Area of G' (mm²), from the boundary by Green's theorem (the pieces'
        gaps at shallow crossings leave it within about 1e-6 of GEOS's area of
        the same union, relative).
    perimeter : float
        Length of ∂G' (mm).
    """

    ax: np.ndarray
    ay: np.ndarray
    bx: np.ndarray
    by: np.ndarray
    rho: np.ndarray
    off: np.ndarray
    ux: np.ndarray
    uy: np.ndarray
    h: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    box: np.ndarray
    k: np.ndarray
    phase: np.ndarray
    grid: tuple
    ex0: np.ndarray
    ey0: np.ndarray
    ex1: np.ndarray
    ey1: np.ndarray
    beyond: np.ndarray
    area: float
    perimeter: float

    @property
    def is_empty(self) -> bool:
        return len(self.ax) == 0

    def polygons(self, index: np.ndarray | None = None) -> np.ndarray:
        """The bead polygons (shapely), all or those of ``index``."""
        idx = np.arange(len(self.ax)) if index is None else np.asarray(index, np.int64)
        rings = [np.column_stack([self.vx[self.off[i]:self.off[i + 1]],
                                  self.vy[self.off[i]:self.off[i + 1]]]) for i in idx]
        return np.array([shapely.Polygon(r) for r in rings], dtype=object)

    def geometry(self):
        """G' as one shapely geometry (a GEOS union: for tests and small inputs)."""
        return shapely.union_all(self.polygons())


def bead_union(p0: np.ndarray, p1: np.ndarray, radius: np.ndarray, *, grow: float,
               inner: float = INNER, workers: int = 1) -> BeadUnion:
    """G' (see the module docs) of the beads ``p0[i] → p1[i]`` of radius ``radius[i]``.

    Parameters
    ----------
    p0, p1
        (n, 2) segment ends, mm.
    radius
        (n,) bead half-widths r > 0, mm.
    grow
        The tolerance τ > 0 the union may stand outside the beads, mm.
    inner
        The inner factor c of the reference polygons (:data:`INNER`).
    workers
        Threads the beads' boundary pieces are computed on (the same union on any number).

    Complexity: O(Σ k_i · m_i) for k_i ≈ π / (2·acos((r + sτ)/(r·c + τ))) edges per
    half turn (s = :data:`SIDE`) and m_i overlapping beads; k is 23 for r = 0.225 mm,
    τ = 0.95 µm.
    """
    p0 = np.ascontiguousarray(p0, dtype=float).reshape(-1, 2)
    p1 = np.ascontiguousarray(p1, dtype=float).reshape(-1, 2)
    r = np.ascontiguousarray(radius, dtype=float).reshape(-1)
    if not (grow > 0 and math.isfinite(grow)):
        raise InputError(f"bead_union needs a positive tolerance to grow by; got {grow!r}")
    if len(r) != len(p0) or len(p1) != len(p0):
        raise InputError("bead_union: p0, p1 and radius must have one row per bead")
    if len(r) and not (np.all(np.isfinite(r)) and r.min() > 0):
        raise InputError("bead_union: every bead radius must be positive and finite")
    rho = r + grow * SIDE
    rmax = r * inner + grow
    if len(r) and np.any(rho >= rmax):
        raise InputError(f"bead_union: the tolerance {grow!r} mm is too small for beads of "
                         f"radius up to {float(r.max())!r} mm")
    ax, ay = np.ascontiguousarray(p0[:, 0]), np.ascontiguousarray(p0[:, 1])
    bx, by = np.ascontiguousarray(p1[:, 0]), np.ascontiguousarray(p1[:, 1])
    if len(r) == 0:
        z = np.zeros(0)
        zi = np.zeros(1, np.int64)
        return BeadUnion(z, z, z, z, z, zi, z, z, z, z, z, np.zeros((0, 4)),
                         np.zeros(0, np.int64), z,
                         (np.zeros(2, np.int64), np.zeros(0, np.int64), 0.0, 0.0, 1.0, 1, 1),
                         z, z, z, z, z, 0.0, 0.0)
    off, ux, uy, h, vx, vy, box, k, phase = _polygons(ax, ay, bx, by, rho, rmax)
    grid = _grid(box)
    parts: dict[int, np.ndarray] = {}

    def run(part: slice) -> None:
        parts[part.start] = _boundary(ax, ay, bx, by, rho, off, ux, uy, h, vx, vy, box, k,
                                      phase, *grid, _EPS, part.start, part.stop)

    shared_out(run, np.ones(len(ax)), workers, min_items=_PARALLEL_MIN)
    edges = parts[0] if len(parts) == 1 else np.concatenate([parts[p] for p in sorted(parts)])
    area = _green(edges, grid[2], grid[3])
    ex0, ey0, ex1, ey1, beyond = (np.ascontiguousarray(edges[:, c]) for c in range(5))
    return BeadUnion(ax, ay, bx, by, rho, off, ux, uy, h, vx, vy, box, k, phase, grid,
                     ex0, ey0, ex1, ey1, beyond, abs(float(area)),
                     float(np.hypot(ex1 - ex0, ey1 - ey0).sum()))


def union_contains_xy(u: BeadUnion, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Whether each point lies in G' (its closure: a point on ∂G' counts), like
    ``shapely.intersects_xy``."""
    x = np.ascontiguousarray(x, dtype=float).reshape(-1)
    y = np.ascontiguousarray(y, dtype=float).reshape(-1)
    out = np.zeros(len(x), dtype=bool)
    if len(u.ax):
        _contains(u.off, u.ux, u.uy, u.h, *u.grid, x, y, out)
    return out


def union_covers(u: BeadUnion, polygons: np.ndarray) -> np.ndarray:
    """``shapely.covers(G', polygon)`` for each polygon, with G' built only where it is.

    A polygon lies in G' exactly when it lies in the union of the bead polygons
    meeting its bounding box, so each test unions a handful of convex polygons;
    from :data:`_MANY` polygons on, G' is built whole once (and kept for the next
    calls on the same union).
    """
    polys = np.asarray(polygons, dtype=object).reshape(-1)
    out = np.zeros(len(polys), dtype=bool)
    if len(u.ax) == 0:
        return out
    if len(polys) >= _MANY:
        # many at once (the reference path of the tests): G' whole, built once per union
        return shapely.covers(_whole(u), polys)
    bounds = shapely.bounds(polys)
    for i, (poly, b) in enumerate(zip(polys, bounds, strict=True)):
        near = np.flatnonzero((u.box[:, 0] <= b[2]) & (u.box[:, 2] >= b[0])
                              & (u.box[:, 1] <= b[3]) & (u.box[:, 3] >= b[1]))
        if near.size:
            out[i] = bool(shapely.covers(shapely.union_all(u.polygons(near)), poly))
    return out


_MANY = 32
_whole_cache: list[tuple[BeadUnion, object]] = []


def _whole(u: BeadUnion):
    """G' as one prepared GEOS geometry, cached for the last few unions."""
    for v, g in _whole_cache:
        if v is u:
            return g
    g = u.geometry()
    shapely.prepare(g)
    _whole_cache.insert(0, (u, g))
    del _whole_cache[4:]
    return g


# ---------------------------------------------------------------------------- kernels


@numba.njit(cache=True, nogil=True)
def _polygons(ax, ay, bx, by, rho, rmax):  # pragma: no cover
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


def _grid(box: np.ndarray) -> tuple:
    """Uniform grid over the polygons' boxes, about one polygon per cell (CSR)."""
    x0, y0 = float(box[:, 0].min()), float(box[:, 1].min())
    w = float(box[:, 2].max()) - x0
    hgt = float(box[:, 3].max()) - y0
    cell = max(0.25, math.sqrt(max(w * hgt, 1e-12) / len(box)))
    nx = int(w // cell) + 1
    ny = int(hgt // cell) + 1
    start, items = _bin_boxes(box[:, 0], box[:, 1], box[:, 2], box[:, 3], x0, y0, cell, nx, ny)
    return start, items, x0, y0, cell, nx, ny


@numba.njit(cache=True, nogil=True)
def _clip(px, py, qx, qy, ux, uy, h, a, b, margin, turn, nx, ny):  # pragma: no cover
    """The parameter interval of [p, q] inside the half-planes ``a:b``, each moved out by
    ``margin`` plus ``turn`` × (1 − cos) of its angle to the edge's normal (nx, ny)
    (Liang–Barsky); empty when t1 <= t0."""
    t0 = 0.0
    t1 = 1.0
    dx = qx - px
    dy = qy - py
    for j in range(a, b):
        t0, t1 = _bound(ux, uy, h, j, px, py, dx, dy, margin, turn, nx, ny, t0, t1)
        if t1 <= t0:
            return 1.0, 0.0
    return t0, t1


@numba.njit(cache=True, nogil=True, inline="always")
def _bound(ux, uy, h, j, px, py, dx, dy, margin, turn, nx, ny, t0, t1):  # pragma: no cover
    """One Liang–Barsky step of :func:`_clip`: [t0, t1] cut by half-plane ``j`` (an empty
    interval, t1 <= t0, when the edge runs parallel outside it)."""
    return _clip_step(ux[j] * dx + uy[j] * dy,
                      h[j] + margin + turn * (1.0 - (ux[j] * nx + uy[j] * ny))
                      - (ux[j] * px + uy[j] * py), t0, t1)


_SAFE = 1e-8
"""Margin (mm) by which a half-plane :func:`_clip_windows` skips must hold both ends of the
edge: far above the rounding of the offsets (about 1e-13 mm), far below the bead sizes."""


@numba.njit(cache=True, nogil=True)
def _window(x, y, ax, ay, bx, by, lx, ly, rho, k, phase, eps, vck):  # pragma: no cover
    """The cap planes of C_j (segment [a, b], left normal ``l``, k edges per half turn, cap
    planes ``phase`` clockwise of l, side offset ``rho``) that may not hold the point x by
    :data:`_SAFE`: ``(r*, w)``, the cap planes ``r* - w … r* + w`` (mod 2k, counted
    clockwise from the one just past l: :func:`_cap_plane`); ``w = -1`` none,
    ``w >= k // 2`` all (no window saves).

    With s the point of [a, b] nearest x and d = x − s, every plane l of C_j holds
    ``u_l·s ≤ h_l − ρ``, so ``u_l·x ≤ h_l − ρ + |d| cos Δ_l`` with Δ_l its angle to d:
    when ``|d| cos Δ_l ≤ ρ − ε − _SAFE`` it holds x with room to spare, whatever
    :func:`_clip`'s margins (at least −ε). Cap plane r* is the nearest to d's direction, so
    the one m steps from it is at least (m − ½)·π/k from d, and ``vck[m - 1]`` =
    cos((m − ½)·π/k) bounds its cos Δ. (The two sides are always clipped.)
    """
    ex, ey = _segment_offset(x, y, ax, ay, bx, by)
    d2 = ex * ex + ey * ey
    lim = rho - eps - _SAFE
    if d2 <= lim * lim:
        return 0, -1
    c = lim / math.sqrt(d2) - 1e-12  # (the slack covers the rounding of the angle)
    w = 0
    while w < k and vck[w] > c:
        w += 1
    if w >= k // 2:
        return 0, k
    # the angle of d from l towards the segment's direction t = (ly, -lx) (clockwise)
    phi = math.atan2(ex * ly - ey * lx, ex * lx + ey * ly)
    return math.floor((phi - phase) * k / math.pi + 0.5), w


@numba.njit(cache=True, nogil=True, inline="always")
def _cap_plane(r, k):  # pragma: no cover
    """The index in its polygon of cap plane r (mod 2k, clockwise from the one just past the
    left side): the k planes of the cap at b follow the left side, the cap at a's the right
    side."""
    r = r % (2 * k)
    return 1 + r if r < k else 2 + r


@numba.njit(cache=True, nogil=True)
def _clip_windows(px, py, qx, qy, ux, uy, h, a, b, margin, turn, nx, ny, j1, w1, j2,
                  w2):  # pragma: no cover
    """:func:`_clip`'s interval over the half-planes ``a:b`` of C_j: its two sides and the
    cap planes in the two ends' windows ``(r, w)`` (:func:`_window`; all of them when
    either is ``w >= k // 2``).

    A plane outside both windows holds both ends strictly, so its Liang–Barsky parameter
    lies beyond [0, 1] on the side it bounds: it moves neither t0 nor t1, and the
    interval (hence the boundary) is the full loop's to the bit. Most edges of a cap face
    a few planes of a neighbour (about 6 of 48 at τ = 1e-3 mm); the full loop runs where
    the ends are too far out for a window to save (w ≥ k/2).

    Any superset of the planes the windows keep gives the same bits (min and max do not
    depend on the order), so windows that overlap or nearly touch are evaluated as the one
    arc that spans both, each plane once: the two ends of a short edge mostly face the
    same few planes.
    """
    k = (b - a - 2) // 2
    if w1 >= k // 2 or w2 >= k // 2:
        return _clip(px, py, qx, qy, ux, uy, h, a, b, margin, turn, nx, ny)
    t0 = 0.0
    t1 = 1.0
    dx = qx - px
    dy = qy - py
    for j in (a, a + k + 1):  # the sides
        t0, t1 = _bound(ux, uy, h, j, px, py, dx, dy, margin, turn, nx, ny, t0, t1)
        if t1 <= t0:
            return 1.0, 0.0
    if w1 >= 0 and w2 >= 0:
        # window 2 seen from window 1's centre, the shorter way round
        delta = (j2 - j1 + k) % (2 * k) - k
        lo = min(-w1, delta - w2)
        hi = max(w1, delta + w2)
        if hi - lo <= 2 * (w1 + w2) + 1:
            for m in range(lo, hi + 1):
                j = a + _cap_plane(j1 + m, k)
                t0, t1 = _bound(ux, uy, h, j, px, py, dx, dy, margin, turn, nx, ny, t0, t1)
                if t1 <= t0:
                    return 1.0, 0.0
            return t0, t1
    for end in range(2):
        js = j1 if end == 0 else j2
        w = w1 if end == 0 else w2
        for mm in range(2 * w + 1):  # the nearest plane first, then ±1, ±2…
            m = (mm + 1) // 2 if mm % 2 else -(mm // 2)
            j = a + _cap_plane(js + m, k)
            t0, t1 = _bound(ux, uy, h, j, px, py, dx, dy, margin, turn, nx, ny, t0, t1)
            if t1 <= t0:
                return 1.0, 0.0
    return t0, t1


@numba.njit(cache=True, nogil=True)
def _corner_cosines(k):  # pragma: no cover
    """cos((w + ½)·π/k) for w < k, per edge count k (per half turn) of the polygons."""
    kmax = 2
    for i in range(len(k)):
        kmax = max(kmax, k[i])
    vc = np.ones((kmax + 1, kmax))
    for i in range(len(k)):
        kk = k[i]
        if vc[kk, 0] == 1.0:
            for w in range(kk):
                vc[kk, w] = math.cos((w + 0.5) * math.pi / kk)
    return vc


@numba.njit(cache=True, nogil=True)
def _boundary(ax, ay, bx, by, rho, off, ux, uy, h, vx, vy, box, k, phase, start, items, x0, y0,
              cell, nx, ny, eps, lo, hi):  # pragma: no cover
    """The uncovered pieces of the edges of polygons ``lo … hi - 1`` (the tie rule of the
    module docs), in order: what each polygon keeps depends on the polygons only. Rows
    (x0, y0, x1, y1, how far the piece's line stands beyond ρ from its bead's path)."""
    n = len(ax)
    mark = np.full(n, -1, np.int64)
    near = np.empty(n, np.int64)
    t_lo = np.empty(n + 2)
    t_hi = np.empty(n + 2)
    cap = max(1024, 8 * (hi - lo))
    out = np.empty((cap, 5))
    vc = _corner_cosines(k)
    # per slot of ``near``: the corner (index into vx, vy) whose window against that
    # neighbour is kept, and the window
    w_at = np.full(n, -1, np.int64)
    w_j = np.empty(n, np.int64)
    w_w = np.empty(n, np.int64)
    n_out = 0
    for i in range(lo, hi):
        # the polygons that may overlap this one: the neighbours along the path first
        # (they cover most of a cap, ending the scans below early)
        m = 0
        big_i = (box[i, 2] - box[i, 0] - abs(bx[i] - ax[i])) * 0.5
        for j in range(i - 1, i + 2, 2):
            if 0 <= j < n:
                mark[j] = i
                near[m] = j
                m += 1
        both = m == 2  # near[0] = i - 1, near[1] = i + 1
        for iy in range(_cell(box[i, 1], y0, cell, ny), _cell(box[i, 3], y0, cell, ny) + 1):
            for ix in range(_cell(box[i, 0], x0, cell, nx), _cell(box[i, 2], x0, cell, nx) + 1):
                c = iy * nx + ix
                for q in range(start[c], start[c + 1]):
                    j = items[q]
                    if j == i or mark[j] == i:
                        continue
                    mark[j] = i
                    if box[j, 0] > box[i, 2] or box[j, 2] < box[i, 0] \
                            or box[j, 1] > box[i, 3] or box[j, 3] < box[i, 1]:
                        continue
                    big_j = (box[j, 2] - box[j, 0] - abs(bx[j] - ax[j])) * 0.5
                    if _segments2(ax[i], ay[i], bx[i], by[i], ax[j], ay[j], bx[j],
                                  by[j]) >= (big_i + big_j) ** 2:
                        continue
                    near[m] = j
                    m += 1
        first = off[i]
        d = off[i + 1] - first
        for e in range(d):
            q1 = first + e
            q0 = first + (e - 1 if e > 0 else d - 1)
            px = vx[q0]
            py = vy[q0]
            qx = vx[q1]
            qy = vy[q1]
            # how far the edge's line stands beyond rho from the path: 0 on the caps, the
            # sides touch Q's extreme corners
            beyond = 0.0
            if e == 0 or e == k[i] + 1:
                beyond = h[q1] - max(ux[q1] * ax[i] + uy[q1] * ay[i],
                                     ux[q1] * bx[i] + uy[q1] * by[i]) - rho[i]
            lo_x = min(px, qx)
            hi_x = max(px, qx)
            lo_y = min(py, qy)
            hi_y = max(py, qy)
            half = 0.5 * math.sqrt((qx - px) ** 2 + (qy - py) ** 2)  # (libm hypot: 3 % of all)
            mx = 0.5 * (px + qx)
            my = 0.5 * (py + qy)
            n_iv = 0
            covered = False
            # the cap at b (edges 1 … k) is mostly inside the next chord's polygon
            ahead = both and 0 < e <= k[i]
            for mm in range(m):
                sl = 1 - mm if ahead and mm < 2 else mm
                j = near[sl]
                if box[j, 0] > hi_x or box[j, 2] < lo_x or box[j, 1] > hi_y or box[j, 3] < lo_y:
                    continue
                d2 = _point_segment2(mx, my, ax[j], ay[j], bx[j], by[j])
                big_j = (box[j, 2] - box[j, 0] - abs(bx[j] - ax[j])) * 0.5
                if d2 > (big_j + half) ** 2:
                    continue  # the edge stays outside the circumscribed capsule
                if half < rho[j] - eps and d2 < (rho[j] - eps - half) ** 2:
                    covered = True  # inside the inscribed capsule, deeper than eps
                    break
                # the ends' windows; an edge's start is the last edge's end, whose
                # window against this neighbour is kept from its clip
                kj = k[j]
                if w_at[sl] == q0:
                    j1 = w_j[sl]
                    w1 = w_w[sl]
                else:
                    j1, w1 = _window(px, py, ax[j], ay[j], bx[j], by[j], ux[off[j]],
                                     uy[off[j]], rho[j], kj, phase[j], eps, vc[kj])
                j2, w2 = _window(qx, qy, ax[j], ay[j], bx[j], by[j], ux[off[j]], uy[off[j]],
                                 rho[j], kj, phase[j], eps, vc[kj])
                w_at[sl] = q1
                w_j[sl] = j2
                w_w[sl] = w2
                t0, t1 = _clip_windows(px, py, qx, qy, ux, uy, h, off[j], off[j + 1],
                                       eps if j < i else -eps, eps, ux[q1], uy[q1], j1, w1,
                                       j2, w2)
                if t1 > t0:
                    if t0 <= 0.0 and t1 >= 1.0:
                        covered = True
                        break
                    s = n_iv  # insertion by start: the lists are short
                    while s > 0 and t_lo[s - 1] > t0:
                        t_lo[s] = t_lo[s - 1]
                        t_hi[s] = t_hi[s - 1]
                        s -= 1
                    t_lo[s] = t0
                    t_hi[s] = t1
                    n_iv += 1
            if covered:
                continue
            t = 0.0
            for s in range(n_iv + 1):
                s0 = t_lo[s] if s < n_iv else 1.0
                s1 = t_hi[s] if s < n_iv else 1.0
                if s0 > t:
                    if n_out == cap:
                        cap *= 2
                        grown = np.empty((cap, 5))
                        grown[:n_out] = out[:n_out]
                        out = grown
                    e1 = min(s0, 1.0)
                    x0_ = px + t * (qx - px)
                    y0_ = py + t * (qy - py)
                    x1_ = px + e1 * (qx - px)
                    y1_ = py + e1 * (qy - py)
                    out[n_out, 0] = x0_
                    out[n_out, 1] = y0_
                    out[n_out, 2] = x1_
                    out[n_out, 3] = y1_
                    out[n_out, 4] = beyond
                    n_out += 1
                if s1 > t:
                    t = s1
                if t >= 1.0:
                    break
    return out[:n_out]


@numba.njit(cache=True, nogil=True)
def _green(edges, x0, y0):  # pragma: no cover
    """The signed area the edges enclose (Green's theorem, about ``(x0, y0)``), summed in
    their order."""
    area = 0.0
    for q in range(edges.shape[0]):
        area += 0.5 * ((edges[q, 0] - x0) * (edges[q, 3] - y0)
                       - (edges[q, 2] - x0) * (edges[q, 1] - y0))
    return area


@numba.njit(cache=True, nogil=True)
def _contains(off, ux, uy, h, start, items, x0, y0, cell, nx, ny, x, y, out):  # pragma: no cover
    """Points in any bead polygon (closed), through the grid."""
    for p in range(len(x)):
        out[p] = in_polygons(x[p], y[p], off, ux, uy, h, start, items, x0, y0, cell, nx, ny)


@numba.njit(cache=True, nogil=True)
def in_polygons(px, py, off, ux, uy, h, start, items, x0, y0, cell, nx, ny):  # pragma: no cover
    """Whether the point lies in one of the bead polygons (closed): a point of G'."""
    c = _cell(py, y0, cell, ny) * nx + _cell(px, x0, cell, nx)
    for q in range(start[c], start[c + 1]):
        i = items[q]
        inside = True
        for j in range(off[i], off[i + 1]):
            if ux[j] * px + uy[j] * py > h[j]:
                inside = False
                break
        if inside:
            return True
    return False

"""Half-planes and ring of an ellipse or rectangle swept along a move; its refusal shortcut.

A swept footprint is the intersection of half-planes ``cu·x + su·y ≤ h`` in d
directions turned with the move: :func:`move_directions` gives the directions and
the move's extent along them (shared by the candidates of a move),
:func:`piece_offsets` the offsets of one piece at one orientation, and
:func:`swept_kernel` the ring (where adjacent boundary lines cross). The fused
kernel of :mod:`printability.planning._first_fits` calls the same two functions,
so its half-planes are those of the ring to the last bit.

:func:`_deep_in_sweep` (:func:`sweep_frame`, then :func:`deep_in_frame` per
edge) is a sufficient test of refusal needing no half-plane, in the frame where
the swept ellipse is the unit disk.

Lengths in mm; orientations as cos/sin pairs.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.planning._kernels import segments2 as _segments2

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = [
    "_deep_in_sweep",
    "candidate_pose",
    "deep_in_frame",
    "move_directions",
    "move_normal",
    "piece_offsets",
    "piece_tuple",
    "sweep_frame",
    "swept_kernel",
]


_DEEP = 1e-3
"""Relative margin of :func:`_deep_in_sweep`: orders above rounding, far below a footprint."""


@numba.njit(cache=True)
def _deep_in_sweep(e0, e1, s, piece, c, sn, sc):  # pragma: no cover
    """Whether the edge [e0, e1] (points relative to the move's start) has a piece well inside
    the ellipse of ``piece`` (:func:`piece_tuple`: its semi-axes, centre and rotation) at
    orientation ``c``, ``sn`` scaled by ``sc`` swept from 0 to ``s``.

    In the frame where that ellipse is the unit disk the swept set is the set of points
    within 1 of a segment; an edge within ``1 - _DEEP`` of it has a piece longer than
    ``_DEEP / 2 · min(a, b) · sc`` (or the whole edge) more than that deep in the swept
    set, hence in every polygon around it, far beyond ``EPS``. A sufficient test of
    refusal, needing no half-plane: a rectangle holds the ellipse of its semi-axes.
    """
    frame = sweep_frame(s[0], s[1], piece, c, sn, sc)
    return deep_in_frame(e0[0], e0[1], e1[0], e1[1], frame)


@numba.njit(cache=True, _nrt=False)
def sweep_frame(sx, sy, piece, c, s, sc):  # pragma: no cover
    """The frame of :func:`_deep_in_sweep` for ``piece`` (:func:`piece_tuple`): its map ``M`` (row
    by row), the ellipse's centre ``q`` and the segment's end ``t`` in it (one per
    footprint, shared by the edges tried), as the tuple ``(m00, m01, m10, m11, qx, qy, tx,
    ty)``."""
    _, a, b, cx, cy, rc, rs = piece
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


@numba.njit(cache=True, _nrt=False)
def deep_in_frame(ex0, ey0, ex1, ey1, frame):  # pragma: no cover
    """:func:`_deep_in_sweep` given its :func:`sweep_frame`."""
    m00, m01, m10, m11, qx, qy, tx, ty = frame
    ax = m00 * ex0 + m01 * ey0
    ay = m10 * ex0 + m11 * ey0
    bx = m00 * ex1 + m01 * ey1
    by = m10 * ex1 + m11 * ey1
    lim = 1.0 - _DEEP
    return _segments2(ax, ay, bx, by, qx, qy, tx, ty) < lim * lim


@numba.njit(cache=True, _nrt=False)
def move_normal(p0x, p0y, p1x, p1y):  # pragma: no cover
    """The unit normal (cos, sin) of the move ``p0 → p1``, its direction turned by +90°
    ((1, 0) for a move of no length): :func:`printability.planning.footprints._move_normals`
    for one move, the same arithmetic (so the same bits: a square root and two divisions,
    each correctly rounded)."""
    dx = p1x - p0x
    dy = p1y - p0y
    length = math.sqrt(dx * dx + dy * dy)
    if length > 0.0:
        return -dy / length, dx / length
    return 1.0, 0.0


@numba.njit(cache=True, _nrt=False)
def move_directions(cn, sn, cb, sb, p0x, p0y, p1x, p1y, cu, su, w):  # pragma: no cover
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
def piece_offsets(piece, pose, cu, su, w, h):  # pragma: no cover
    """Offsets ``h`` of the half-planes of ``piece`` (:func:`piece_tuple`: an ellipse, kind 0, or a
    rectangle, 1) swept at the :func:`candidate_pose` ``pose``, given the directions ``cu``, ``su``
    and the move's extent ``w`` along them (:func:`move_directions`).

    The swept_kernel's arithmetic, shared with the fused tests so that their
    half-planes are those of the ring, to the last bit.
    """
    kind, a, b, cx, cy, rc, rs = piece
    c0, s0, c1, s1, k, turning, scale, scaled = pose
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


@numba.njit(cache=True, _nrt=False, inline="always")
def piece_tuple(pieces, p):  # pragma: no cover
    """Piece ``p`` of ``pieces`` (a :class:`~printability.planning.records.Pieces`) as the
    tuple ``(kind, a, b, cx, cy, rc, rs)`` of :func:`piece_offsets` and :func:`sweep_frame`
    (:func:`printability.planning.footprints._piece_params`'s)."""
    return (pieces.kind[p], pieces.a[p], pieces.b[p], pieces.cx[p], pieces.cy[p],
            pieces.rc[p], pieces.rs[p])


@numba.njit(cache=True, _nrt=False, inline="always")
def candidate_pose(angles, q, scale, m):  # pragma: no cover
    """The orientation of candidate ``q`` of ``angles`` (an
    :class:`~printability.planning.records.Angles`) and the scale of segment ``m``
    (``scale`` empty: 1), as :func:`piece_offsets` reads them: ``(c0, s0, c1, s1, k, turning,
    scale, scaled)``."""
    turning = len(angles.k) > 0
    scaled = len(scale) > 0
    return (angles.c0[q], angles.s0[q], angles.c1[q] if turning else 0.0,
            angles.s1[q] if turning else 0.0, angles.k[q] if turning else 1.0, turning,
            scale[m] if scaled else 1.0, scaled)


@numba.njit(cache=True)
def swept_kernel(piece, moves, normals, dirs, angles, planes, ring):  # pragma: no cover
    """Half-plane offsets and ring of ``piece`` (``(kind, a, b, cx, cy, rc, rs)``: an
    ellipse, kind 0, or a rectangle, 1, :func:`piece_tuple`) swept along each of ``moves`` at
    ``angles`` (row i at row i).

    The same arithmetic, in the same order, as the numpy path of
    :func:`printability.planning.footprints.swept_rings` (so the same rings to
    the last bit), fused into one pass: numpy makes a dozen (n, 64)
    temporaries per call, which cost more than the arithmetic. The end orientations
    (turning moves) are used when ``angles.k`` is non-empty, ``moves.scale`` when
    non-empty; ``planes`` (``cu``, ``su``, ``h``, each (n, d)) is filled: the directions
    from the moves' normals ``normals`` (``cn``, ``sn``) and the base directions of
    ``dirs`` (a :class:`~printability.planning.records.Directions`), and the offsets.
    """
    cu, su, h = planes
    cn, sn = normals
    p0 = moves.p0
    p1 = moves.p1
    det = dirs.det
    n, d = cu.shape
    w = np.empty(d)
    for i in range(n):
        move_directions(cn[i], sn[i], dirs.cb, dirs.sb, p0[i, 0], p0[i, 1], p1[i, 0], p1[i, 1],
                        cu[i], su[i], w)
        piece_offsets(piece, candidate_pose(angles, i, moves.scale, i), cu[i], su[i], w, h[i])
        for j in range(d):
            jn = j + 1 if j + 1 < d else 0
            ring[i, j, 0] = (h[i, j] * su[i, jn] - h[i, jn] * su[i, j]) / det
            ring[i, j, 1] = (cu[i, j] * h[i, jn] - cu[i, jn] * h[i, j]) / det
        ring[i, d, 0] = ring[i, 0, 0]
        ring[i, d, 1] = ring[i, 0, 1]

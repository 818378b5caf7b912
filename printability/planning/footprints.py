"""Swept nozzle footprints and the test "does this move fit inside the target?".

A move from p₀ to p₁ at the constant orientation φ deposits inside the swept
footprint ``[p₀, p₁] ⊕ R(φ)A⁰``. For a convex orifice that is the convex hull
of the footprint placed at both ends; a non-convex polygon is split into
triangles (:meth:`~printability.model.nozzle.Nozzle.convex_pieces`) and each is swept.
Footprints are tested with
their *outer* polygonal approximation (half-planes in 64 directions, one of them
the move's normal), so curved orifices are never under-estimated. The planner
(:mod:`printability.planning.orientation`) asks :func:`fits` and :func:`_first_fit`
(the first fitting candidate of each group); ellipses and rectangles go through
the fused kernels of :mod:`printability.planning.fastfit`, other pieces through
their rings and ``shapely.covers``.

Conventions: lengths in mm, angles in degrees (radians inside the kernels).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from printability.base.parallel import shared_out
from printability.errors import InputError
from printability.model.nozzle import Nozzle
from printability.model.shapes import POLYGON, Footprint
from printability.planning.fastfit import (
    EPS,
    boundary_grid,
    covers,
    covers_rings,
    direction_order,
    first_fits,
    locator,
    swept_kernel,
)
from printability.planning.records import Angles, Directions, Groups, Moves, Pieces

__all__ = ["convex_pieces", "fits", "grown_target", "swept_footprints",
           "swept_rings"]


def convex_pieces(nozzle: Nozzle, *, quad_segs: int = 16) -> list[Footprint]:
    """Convex pieces covering the orifices of a nozzle, exactly
    (:meth:`~printability.model.nozzle.Nozzle.convex_pieces`).

    Circles, ellipses and rectangles are one piece each (their support
    function is exact); a convex polygon is one piece; a non-convex polygon
    is triangulated (constrained Delaunay). ``quad_segs`` is unused (kept for
    symmetry with the outline functions).
    """
    del quad_segs
    return list(nozzle.convex_pieces())


def swept_footprints(piece: Footprint, p0: np.ndarray, p1: np.ndarray, angle: np.ndarray,
                     *, angle_end: np.ndarray | None = None, scale: np.ndarray | None = None,
                     directions: int = 64) -> np.ndarray:
    """Outer polygons of a convex piece swept from p0 to p1.

    The piece is turned by ``angle`` (and, when ``angle_end`` is given, turns
    linearly to it during the move) and scaled by ``scale`` about the nozzle
    origin. The polygon is the intersection of the ``directions`` half-planes
    tangent to the swept set, so it *contains* the swept set (it exceeds it by
    at most ρ·(1/cos(π/directions) − 1) for a curved piece at radius ρ: 0.05 %).
    A piece turning from φa to φb is bounded by k·hull(R(φa)A ∪ R(φb)A),
    k = 1/cos(|φb − φa|/2): every point of a turning orifice stays on an arc
    whose chord lies in that hull and the arc bulges outwards by at most that
    factor.

    Returns
    -------
    ndarray of shapely Polygons, shape (n,).
    """
    return shapely.polygons(swept_rings(piece, p0, p1, angle, angle_end=angle_end, scale=scale,
                                        directions=directions))


def swept_rings(piece: Footprint, p0: np.ndarray, p1: np.ndarray, angle: np.ndarray,
                *, angle_end: np.ndarray | None = None, scale: np.ndarray | None = None,
                directions: int = 64) -> np.ndarray:
    """The closed rings of :func:`swept_footprints` as coordinates, shape (n, directions + 1, 2)."""
    return _swept(piece, p0, p1, angle, angle_end=angle_end, scale=scale,
                  directions=directions)[0]


_EMPTY = np.zeros(0)
_PARALLEL_MIN = 128
"""Fewest groups of candidates :func:`_first_fit` gives a thread of its own."""


def _piece_params(piece: Footprint) -> tuple[int, float, float, float, float, float, float]:
    """Shape code (:data:`~printability.model.shapes.CONIC` or
    :data:`~printability.model.shapes.BOX`), semi-axes, centre and rotation cos/sin of a piece."""
    r = math.radians(piece.rotation)
    return (piece.code, float(piece.a), float(piece.b),
            float(piece.center[0]), float(piece.center[1]), math.cos(r), math.sin(r))


def _angle_trig(angle, angle_end, n: int):
    """cos/sin of the orientations (and of the end ones, with the bulge factor k), per row.

    Numpy's elementwise results depend on the values only, so rows computed in
    any batch are the same bits: the fused tests and the rings agree.
    """
    phi = np.deg2rad(np.asarray(angle, dtype=float)).reshape(n)
    if angle_end is None:
        return np.cos(phi), np.sin(phi), _EMPTY, _EMPTY, _EMPTY
    phi1 = np.deg2rad(np.asarray(angle_end, dtype=float)).reshape(n)
    d = np.abs(np.asarray(angle_end, dtype=float) - angle)
    k = 1.0 / np.cos(np.deg2rad(np.minimum(d, 120.0)) / 2.0)
    return np.cos(phi), np.sin(phi), np.cos(phi1), np.sin(phi1), np.ascontiguousarray(k)


def _move_normals(p0: np.ndarray, p1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The unit normal (cos, sin) of each move ``p0 → p1``: its direction turned by +90°
    ((1, 0) for a move of no length). The directions of the swept footprints are turned by
    it, in :func:`_swept` and in the fused kernels alike (an arctan2, a cos and a sin per
    move cost about ten times the two divisions)."""
    dx = p1[:, 0] - p0[:, 0]
    dy = p1[:, 1] - p0[:, 1]
    length = np.sqrt(dx * dx + dy * dy)  # (mm: far from hypot's overflow)
    if length.all():
        return -dy / length, dx / length
    moving = length > 0
    return (np.divide(-dy, length, out=np.ones_like(length), where=moving),
            np.divide(dx, length, out=np.zeros_like(length), where=moving))


def _swept(piece, p0, p1, angle, *, angle_end=None, scale=None, directions=64,
           kernel=True):
    """Rings and their half-planes: ring (n, d + 1, 2), and u = (cu, su), h of shape (n, d).

    The swept set lies in every half-plane ``cu·x + su·y ≤ h``; the ring's vertices are
    where adjacent boundary lines cross. ``kernel=False`` forces the numpy path (the
    kernel's reference in the tests).
    """
    n = len(p0)
    # The directions are turned so that two of them are normal to the move:
    # the long sides of the swept set are then exact, not cut by a spike.
    normal_c, normal_s = _move_normals(p0, p1)
    base = np.arange(directions) * (2 * math.pi / directions)
    det = math.sin(2 * math.pi / directions)
    if kernel and piece.code != POLYGON:
        c0, s0, c1, s1, k = _angle_trig(angle, angle_end, n)
        sc = _EMPTY if scale is None else np.broadcast_to(np.asarray(scale, dtype=float),
                                                          (n,)).copy()
        cu = np.empty((n, directions))
        su = np.empty((n, directions))
        h = np.empty((n, directions))
        ring = np.empty((n, directions + 1, 2))
        moves = Moves(np.ascontiguousarray(p0, dtype=float), np.ascontiguousarray(p1, dtype=float),
                      sc)
        cb, sb, _ = _base_directions(directions)
        dirs = Directions(cb, sb, det, direction_order(directions))
        swept_kernel(_piece_params(piece), moves, (normal_c, normal_s), dirs,
                     Angles(c0, s0, c1, s1, k), (cu, su, h), ring)
        return ring, cu, su, h
    cn, sn = normal_c[:, None], normal_s[:, None]
    cb, sb = np.cos(base)[None, :], np.sin(base)[None, :]
    cu = cn * cb - sn * sb  # cos(normal + base), without a cos per element
    su = sn * cb + cn * sb

    def h_at(phi: np.ndarray) -> np.ndarray:
        r = np.deg2rad(phi)[:, None]
        c, s = np.cos(r), np.sin(r)
        # u expressed in the nozzle frame: R(-phi) u
        return piece.support(c * cu + s * su, -s * cu + c * su)

    h = h_at(np.asarray(angle, dtype=float))
    if angle_end is not None:
        d = np.abs(np.asarray(angle_end, dtype=float) - angle)
        h = np.maximum(h, h_at(np.asarray(angle_end, dtype=float)))
        k = 1.0 / np.cos(np.deg2rad(np.minimum(d, 120.0)) / 2.0)
        h = h * k[:, None]
    if scale is not None:
        h = h * np.asarray(scale, dtype=float)[:, None]
    h = h + np.maximum(cu * p0[:, :1] + su * p0[:, 1:2], cu * p1[:, :1] + su * p1[:, 1:2])
    # vertex j is where the tangent lines j and j+1 cross; the ring closes on itself
    hh = np.concatenate([h, h[:, :1]], axis=1)
    cc = np.concatenate([cu, cu[:, :1]], axis=1)
    ss = np.concatenate([su, su[:, :1]], axis=1)
    ring = np.empty((n, directions + 1, 2))
    ring[:, :-1, 0] = (hh[:, :-1] * ss[:, 1:] - hh[:, 1:] * ss[:, :-1]) / det
    ring[:, :-1, 1] = (cc[:, :-1] * hh[:, 1:] - cc[:, 1:] * hh[:, :-1]) / det
    ring[:, -1] = ring[:, 0]
    return ring, cu, su, h


def fits(target: BaseGeometry, pieces: Sequence[Footprint], p0: np.ndarray, p1: np.ndarray,
         angle: np.ndarray, *, angle_end: np.ndarray | None = None,
         scale: np.ndarray | None = None, fast: bool = True, workers: int = 1) -> np.ndarray:
    """Whether each move's swept footprint lies inside ``target`` (prepared, grown).

    ``fast`` decides what it can with the exact tests of
    :func:`printability.planning.fastfit.first_fits` (ellipses and rectangles:
    sweep, edge test and point location fused, nothing stored per footprint)
    or :func:`printability.planning.fastfit.covers_rings` (other pieces) and
    leaves only the rest to ``shapely.covers``; ``fast=False`` tests every
    footprint with ``shapely.covers`` (the reference the fast path must agree
    with). The fused tests run on ``workers`` threads.

    Returns a boolean array of shape (n,).
    """
    n = len(p0)
    if n == 0:
        return np.ones(0, dtype=bool)
    if fast and _fused(pieces):
        every = np.arange(n)
        return _first_fit(target, pieces, (p0, p1, scale), every, angle, every, every + 1,
                          angle_end=angle_end, workers=workers) >= 0
    return _fits_rings(target, pieces, p0, p1, angle, angle_end=angle_end, scale=scale,
                       fast=fast)


def _fits_rings(target, pieces, p0, p1, angle, *, angle_end=None, scale=None, fast=True):
    """:func:`fits` through the rings: any convex piece, and the reference of the fused path."""
    n = len(p0)
    ok = np.ones(n, dtype=bool)
    for piece in pieces:
        idx = np.flatnonzero(ok)
        if idx.size == 0:
            break
        rings, cu, su, h = _swept(piece, p0[idx], p1[idx], np.asarray(angle)[idx],
                                  angle_end=None if angle_end is None else angle_end[idx],
                                  scale=None if scale is None else scale[idx])
        if fast:
            ok[idx] = covers_rings(target, rings, cu, su, h)
        else:
            ok[idx] = covers(target, shapely.polygons(rings))
    return ok


def _first_fit_reference(target, pieces, p0, p1, scale, seg, angle, gpos, gend,
                         fast=False) -> np.ndarray:
    """:func:`_first_fit` the slow way: every candidate through the rings of :func:`fits`."""
    ok = _fits_rings(target, pieces, p0[seg], p1[seg], angle,
                     scale=None if scale is None else scale[seg], fast=fast)
    out = np.full(len(gpos), -1, dtype=np.int64)
    for g, (lo, hi) in enumerate(zip(gpos.tolist(), gend.tolist(), strict=True)):
        hit = np.flatnonzero(ok[lo:hi])
        if hit.size:
            out[g] = lo + hit[0]
    return out


@functools.lru_cache(maxsize=8)
def _base_directions(directions: int) -> tuple[np.ndarray, np.ndarray, float]:
    """cos, sin of the base directions (as :func:`_swept` computes them) and det."""
    base = np.arange(directions) * (2 * math.pi / directions)
    cb, sb = np.cos(base), np.sin(base)
    cb.setflags(write=False)
    sb.setflags(write=False)
    return cb, sb, math.sin(2 * math.pi / directions)


@functools.lru_cache(maxsize=32)
def _pieces_arrays(pieces: tuple[Footprint, ...]) -> Pieces:
    """:func:`_piece_params` of every piece, as the kernels' arrays."""
    params = [_piece_params(p) for p in pieces]
    out = Pieces(np.array([q[0] for q in params], dtype=np.int64),
                 *(np.array([q[j] for q in params], dtype=float) for j in range(1, 7)))
    for v in out:
        v.setflags(write=False)
    return out


def _fused(pieces: Sequence[Footprint]) -> bool:
    """Whether :func:`first_fits` sweeps these pieces (conics and rectangles)."""
    return all(p.code != POLYGON for p in pieces)


_DIRECTIONS = 64
"""Half-planes of a swept footprint (as :func:`swept_rings` makes them by default)."""


def _first_fit(target, pieces, segments, seg, angle, gpos, gend, *, angle_end=None, gseg=None,
               trig=None, workers: int = 1) -> np.ndarray:
    """Per group of candidates, the index of the first that fits (-1: none).

    ``segments`` is ``(p0, p1, scale)`` (``scale`` None: 1). Candidate ``q`` is segment
    ``seg[q]`` swept at ``angle[q]`` (turning to ``angle_end[q]``); group ``g`` holds
    candidates ``gpos[g] … gend[g] - 1``, tried in order. With ``gseg``, every candidate of
    group ``g`` is swept along segment ``gseg[g]`` instead (groups may share
    candidates); ``trig`` is ``(cos, sin)`` of the angles in radians when already
    known. The answer per candidate is :func:`fits`'s: footprints ∂G grazes go
    to :func:`covers_rings` with the rings of the same half-planes, and the group
    resumes after a refusal. The groups are shared out over ``workers`` threads (the
    kernel releases the GIL; each group's answer is its own, whichever thread tests it).
    """
    ngroups = len(gpos)
    result = np.full(ngroups, -1, dtype=np.int64)
    if ngroups == 0:
        return result
    moves, angles, dirs = _kernel_inputs(segments, angle, angle_end, trig)
    if gseg is None:
        gseg = np.zeros(0, dtype=np.int64)
        seg = np.ascontiguousarray(seg, dtype=np.int64)
    else:
        gseg = np.ascontiguousarray(gseg, dtype=np.int64)
        seg = np.zeros(0, dtype=np.int64)
    fixed = (_pieces_arrays(tuple(pieces)), moves, angles, seg, dirs, boundary_grid(target),
             locator(target))
    gpos = np.array(gpos, dtype=np.int64)
    gend = np.ascontiguousarray(gend, dtype=np.int64)
    groups = np.arange(ngroups)
    while groups.size:
        out_idx = np.empty(groups.size, dtype=np.int64)
        out_state = np.empty(groups.size, dtype=np.int8)
        g_seg = gseg[groups] if len(gseg) else gseg
        g_pos = gpos[groups]
        g_end = gend[groups]
        run = functools.partial(_first_fits_part, fixed, (g_seg, g_pos, g_end),
                                (out_idx, out_state))
        shared_out(run, g_end - g_pos, workers, min_items=_PARALLEL_MIN)
        fit = out_state == 1
        result[groups[fit]] = out_idx[fit]
        und = np.flatnonzero(out_state == -1)
        if und.size == 0:
            break
        # ∂G grazes these footprints: the rings of the same half-planes, decided exactly
        q = out_idx[und]
        m = gseg[groups[und]] if len(gseg) else seg[q]
        ok = _grazed_fit(target, pieces, fixed, q, m)
        result[groups[und[ok]]] = q[ok]
        rest = und[~ok]
        gpos[groups[rest]] = q[~ok] + 1
        groups = groups[rest]
    return result


def _kernel_inputs(segments, angle, angle_end, trig) -> tuple[Moves, Angles, Directions]:
    """The records :func:`first_fits` reads: the segments, the candidates' orientations
    (``trig``: their cos/sin when known) and the base directions."""
    p0, p1, scale = segments
    p0 = np.ascontiguousarray(p0, dtype=float)
    p1 = np.ascontiguousarray(p1, dtype=float)
    cb, sb, det = _base_directions(_DIRECTIONS)
    if trig is None:
        c0, s0, c1, s1, k = _angle_trig(angle, angle_end, len(angle))
    else:
        c0, s0 = trig
        c1 = s1 = k = _EMPTY
    sc = _EMPTY if scale is None else np.ascontiguousarray(
        np.broadcast_to(np.asarray(scale, dtype=float), (len(p0),)))
    return (Moves(p0, p1, sc), Angles(c0, s0, c1, s1, k),
            Directions(cb, sb, det, direction_order(_DIRECTIONS)))


def _grazed_fit(target, pieces, fixed, q, m) -> np.ndarray:
    """Whether candidates ``q`` (on segments ``m``), which ∂G grazes, fit: the rings of the
    same half-planes (every piece of ``pieces``), decided by :func:`covers_rings`."""
    _, moves, angles, _, dirs, _, _ = fixed
    p0, p1, sc = moves
    c0, s0, c1, s1, k = angles
    turning = len(k) > 0
    sub_moves = Moves(p0[m], p1[m], sc[m] if len(sc) else _EMPTY)
    sub_angles = Angles(c0[q], s0[q], c1[q] if turning else _EMPTY,
                        s1[q] if turning else _EMPTY, k[q] if turning else _EMPTY)
    normals = _move_normals(p0[m], p1[m])
    ok = np.ones(q.size, dtype=bool)
    for piece in pieces:
        nq = q.size
        cu = np.empty((nq, _DIRECTIONS))
        su = np.empty((nq, _DIRECTIONS))
        h = np.empty((nq, _DIRECTIONS))
        ring = np.empty((nq, _DIRECTIONS + 1, 2))
        swept_kernel(_piece_params(piece), sub_moves, normals, dirs, sub_angles, (cu, su, h),
                     ring)
        ok &= covers_rings(target, ring, cu, su, h)
    return ok


def _first_fits_part(fixed, groups, out, part: slice) -> None:
    """:func:`first_fits` on the groups of ``part`` (their answers in ``out[…][part]``)."""
    pieces, moves, angles, seg, dirs, grid, loc = fixed
    g_seg, g_pos, g_end = groups
    out_idx, out_state = out
    first_fits(pieces, moves, angles,
               Groups(seg, g_seg[part] if len(g_seg) else g_seg, g_pos[part], g_end[part]),
               dirs, grid, loc, EPS, out_idx[part], out_state[part])


def grown_target(target: BaseGeometry, tolerance: float) -> BaseGeometry:
    """G grown by ``tolerance`` (mm; negative shrinks it) and prepared for repeated predicates."""
    if target is None or target.is_empty:
        raise InputError("the layer target is empty: there is nothing a move could fit in")
    g = target.buffer(tolerance, quad_segs=8) if tolerance != 0 else target
    shapely.prepare(g)
    return g

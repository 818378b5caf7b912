"""The fused planner kernel: per group of candidates, the first that fits inside G.

:func:`first_fits` sweeps the pieces with the arithmetic of
:mod:`printability.planning._sweep`, tests the edges of ∂G near each footprint as
:mod:`printability.planning._covers` does and locates a point of it with
:mod:`printability.planning._point_location`, storing nothing per footprint;
:func:`_to_front` keeps the few edges that last refused a footprint, tried
first.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.planning._covers import clip_fraction, edges_state
from printability.planning._point_location import locate
from printability.planning._sweep import (
    candidate_pose,
    deep_in_frame,
    move_directions,
    move_normal,
    piece_offsets,
    piece_tuple,
    sweep_frame,
)

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["first_fits"]


class _Scratch(NamedTuple):
    """The working arrays of :func:`first_fits`: the current segment's directions ``cu``,
    ``su`` and extent ``w`` along them, a footprint's offsets ``h``, the edges that last
    refused a footprint (``mru``, their lengths ``mru_len``), the edge the scan found
    (``found[0]``), and whether the segment's start lies in G (``where[0]``: -1 not
    located yet, 0 outside, 1 inside)."""

    cu: np.ndarray
    su: np.ndarray
    w: np.ndarray
    h: np.ndarray
    mru: np.ndarray
    mru_len: np.ndarray
    found: np.ndarray
    where: np.ndarray


@numba.njit(cache=True, nogil=True)
def first_fits(pieces, moves, angles, groups, dirs, grid, loc, eps, out_idx,
               out_state):  # pragma: no cover
    """Per group of candidates, the first whose swept footprint lies inside G.

    Candidate ``q`` sweeps the ``pieces`` (a :class:`~printability.planning.records.Pieces`)
    along segment ``groups.seg[q]`` of ``moves`` (or ``groups.gseg[g]`` for all the
    candidates of group ``g`` when ``gseg`` is non-empty: groups may then share
    candidates; the normal of :func:`move_normal`, the base directions of ``dirs``) at
    the orientation ``angles.c0[q]``, ``angles.s0[q]`` (turning to ``c1``, ``s1`` with
    factor ``k`` when ``angles.k`` is non-empty). Group ``g`` tries ``gpos[g] … gend[g] - 1``
    in order and stops at the first that fits (``out_state`` 1, ``out_idx`` its index), at
    the first ∂G grazes (``out_state`` -1: shapely decides, the caller resumes after it)
    or finds none (``out_state`` 0, ``out_idx`` -1). ``grid`` is ∂G's
    :class:`~printability.planning.records.BoundaryGrid`, ``loc`` :func:`locator`'s: points
    are located in a bead union's polygons.

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
      (:func:`_deep_in_recent`, before any half-plane is computed: most
      candidates end there), then with :func:`clip_fraction`; a segment's directions are found
      only once one of its candidates gets past that test;
    * the point located is the segment's start where it lies in every
      footprint (pieces centred on the nozzle, not mirrored by a negative
      scale: their half-planes hold it, the rounding included, since the
      offsets add a non-negative support to the segment's extent), located
      once per segment: all the points of a footprint that ∂G does not come
      within ``eps`` of are on the same side of ∂G.
    """
    d = len(dirs.cb)
    work = _Scratch(np.empty(d), np.empty(d), np.empty(d), np.empty(d),
                    np.full(4, -1, np.int64), np.zeros(4), np.zeros(1, np.int64),
                    np.full(1, -1, np.int64))
    _groups(pieces, moves, angles, groups, dirs, grid, loc, eps, work, (out_idx, out_state))


@numba.njit(cache=True, _nrt=False)
def _groups(pieces, moves, angles, groups, dirs, grid, loc, eps, work, out):  # pragma: no cover
    """:func:`first_fits`'s loop over the groups, given its working arrays ``work``.

    Compiled without the runtime, as are the steps it inlines (:func:`_deep_in_recent`,
    :func:`_candidate_state` …): arrays read from the records then cost no reference
    counting, and the steps no call.
    """
    out_idx, out_state = out
    turning = len(angles.k) > 0
    centred = _centred(pieces)
    seg, gseg, gpos, gend = groups
    p0 = moves.p0
    p1 = moves.p1
    cb = dirs.cb
    sb = dirs.sb
    where = work.where
    directed = False  # work.cu, su, w are the current segment's
    last = -1
    for g in range(len(gpos)):
        out_idx[g] = -1
        out_state[g] = 0
        for q in range(gpos[g], gend[g]):
            m = gseg[g] if len(gseg) else seg[q]
            if m != last:  # the candidates of a move share its directions
                last = m
                where[0] = -1
                directed = False
            if not turning and _deep_in_recent(pieces, moves, m, angles, q, grid, work):
                continue
            if not directed:  # (found only now: the shortcut above ends most candidates)
                cn, sn = move_normal(p0[m, 0], p0[m, 1], p1[m, 0], p1[m, 1])
                move_directions(cn, sn, cb, sb, p0[m, 0], p0[m, 1], p1[m, 0], p1[m, 1], work.cu,
                                work.su, work.w)
                directed = True
            state = _candidate_state(pieces, moves, m, angles, q, dirs, grid, loc, eps, work,
                                     centred)
            if state != 0:
                out_idx[g] = q
                out_state[g] = state
                break


@numba.njit(cache=True, _nrt=False)
def _centred(pieces):  # pragma: no cover
    """Whether every piece is centred on the nozzle and not mirrored: the segment's start
    then lies in every footprint."""
    for p in range(len(pieces.kind)):
        if pieces.cx[p] != 0.0 or pieces.cy[p] != 0.0 or pieces.a[p] < 0.0 \
                or pieces.b[p] < 0.0:
            return False
    return True


@numba.njit(cache=True, _nrt=False, inline="always")
def _deep_in_recent(pieces, moves, m, angles, q, grid, work):  # pragma: no cover
    """Whether an edge that refused a recent footprint lies deep in the ellipse of a piece
    swept along segment ``m`` at candidate ``q``'s orientation (no turn): a refusal found
    with no half-plane (:func:`deep_in_frame`); the edge moves to the front."""
    p0 = moves.p0
    p1 = moves.p1
    ex0, ey0, ex1, ey1 = grid.ex0, grid.ey0, grid.ex1, grid.ey1
    mru = work.mru
    mru_len = work.mru_len
    sc = moves.scale[m] if len(moves.scale) > 0 else 1.0
    for p in range(len(pieces.kind)):
        a = pieces.a[p]
        b = pieces.b[p]
        if a <= 0.0 or b <= 0.0 or not sc * min(a, b) >= 1e-3:
            continue
        sx = p1[m, 0] - p0[m, 0]
        sy = p1[m, 1] - p0[m, 1]
        frame = sweep_frame(sx, sy, piece_tuple(pieces, p), angles.c0[q], angles.s0[q], sc)
        for r in range(len(mru)):
            e = mru[r]
            if e < 0:
                break
            if mru_len[r] < 1e-6:
                continue
            if deep_in_frame(ex0[e] - p0[m, 0], ey0[e] - p0[m, 1], ex1[e] - p0[m, 0],
                             ey1[e] - p0[m, 1], frame):
                _to_front(mru, mru_len, r, e, mru_len[r])
                return True
    return False


@numba.njit(cache=True, _nrt=False, inline="always")
def _candidate_state(pieces, moves, m, angles, q, dirs, grid, loc, eps, work,
                     centred):  # pragma: no cover
    """Candidate ``q`` on segment ``m`` (whose directions ``work`` holds): 1 inside, 0 not
    inside, -1 undecided (∂G grazes a piece and none pokes out), piece by piece."""
    state = 1
    for p in range(len(pieces.kind)):
        piece_offsets(piece_tuple(pieces, p), candidate_pose(angles, q, moves.scale, m), work.cu,
                      work.su, work.w, work.h)
        if _refused_by_recent(grid, eps, dirs.order, work):
            return 0
        st, vx, vy = _scan(grid, eps, dirs, work)
        if st == 0:
            return 0
        if st == 1:
            if centred and not (len(moves.scale) > 0 and moves.scale[m] < 0.0):
                # the segment's start lies in the footprint: located once per segment
                if work.where[0] < 0:
                    work.where[0] = 1 if locate(moves.p0[m, 0], moves.p0[m, 1], grid,
                                                loc) else 0
                inside = work.where[0] == 1
            else:
                inside = locate(vx, vy, grid, loc)
            if not inside:
                return 0
        if st == -1:
            state = -1  # still 0 if another piece pokes out
    return state


@numba.njit(cache=True, _nrt=False, inline="always")
def _refused_by_recent(grid, eps, order, work):  # pragma: no cover
    """Whether an edge that refused a recent footprint has a piece inside this one (the
    half-planes in ``work``): only the refusal test, the shortcut never accepts, so whether
    the edge meets the footprint grown by ``eps`` is left to the scan."""
    mru = work.mru
    mru_len = work.mru_len
    for r in range(len(mru)):
        e = mru[r]
        if e < 0:
            break
        t = clip_fraction(grid.ex0[e], grid.ey0[e], grid.ex1[e], grid.ey1[e], work.cu, work.su,
                          work.h, -eps, order)
        if t > 0.0 and t * mru_len[r] > eps:
            _to_front(mru, mru_len, r, e, mru_len[r])
            return True
    return False


@numba.njit(cache=True, _nrt=False, inline="always")
def _scan(grid, eps, dirs, work):  # pragma: no cover
    """The edge test of the footprint whose half-planes ``work`` holds, on the edges of ∂G
    near its ring's box (:func:`edges_state`): its state and the ring's first vertex. An
    edge entering it moves to the front of the recent ones."""
    cu = work.cu
    su = work.su
    h = work.h
    det = dirs.det
    d = len(cu)
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
    box = (mx0 / det - eps, my0 / det - eps, mx1 / det + eps, my1 / det + eps)
    st = edges_state(cu, su, h, box, grid.cells, grid.packed, eps, dirs.order, work.found)
    if st == 0:
        e = work.found[0]
        _to_front(work.mru, work.mru_len, len(work.mru) - 1, e,
                  math.sqrt((grid.ex1[e] - grid.ex0[e]) ** 2 + (grid.ey1[e] - grid.ey0[e]) ** 2))
    return st, nx0 / det, ny0 / det


@numba.njit(cache=True, _nrt=False)
def _to_front(mru, mru_len, r, e, length):  # pragma: no cover
    """Move edge ``e`` (of length ``length``) to the front of the most recently used edges,
    from slot ``r`` (or the last one: the edge drops out)."""
    for rr in range(r, 0, -1):
        mru[rr] = mru[rr - 1]
        mru_len[rr] = mru_len[rr - 1]
    mru[0] = e
    mru_len[0] = length

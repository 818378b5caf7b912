"""The pieces of a group of moves compiled: what ``printability.generate._pieces`` makes
for the compiled writer (:func:`printability.generate._emit_kernel.emit`), with the same operations.

A move is one piece at its planned orientation, or the planner's pieces where it is split;
each piece's bead width is the nozzle's across its direction
(:meth:`printability.model.nozzle.Nozzle.bead_width`, for circles, ellipses and rectangles:
:func:`measures`). :func:`pieces_of` takes the group's moves, the planner's pieces
and the nozzle's orifice (:class:`Orifice`) as tuples of columns, and returns the pieces as
:class:`~printability.generate._emit_kernel.Pieces`' columns.

Complexity: linear in the pieces times the footprints.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from gcode.text_kernels import hypot
from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.model.shapes import BOX, CONIC

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["Orifice", "measures", "orifice_of", "pieces_of"]


class Orifice(NamedTuple):
    """The nozzle's footprints as columns: shape code
    (:attr:`~printability.model.shapes.Footprint.code`), semi-axes or half sides, centre and
    rotation in the nozzle's frame. (Columns, not rows of a record: made on each call of the
    generator's, a table cost a third of :func:`pieces_of`'s time.)"""

    kind: np.ndarray
    a: np.ndarray
    b: np.ndarray
    cx: np.ndarray
    cy: np.ndarray
    rotation: np.ndarray


@numba.njit(cache=True, nogil=True)
def _bead_width(direction, angle, mount, fk, fa, fb, fcx, fcy, frot):  # pragma: no cover
    """:meth:`printability.model.nozzle.Nozzle.bead_width` of circles, ellipses (``fk`` 0) and
    rectangles (1) (an :class:`Orifice`'s columns): the same operations (numba's
    trigonometry is the C library's, as :mod:`math`'s)."""
    theta = math.radians(direction)
    nx = -math.sin(theta)
    ny = math.cos(theta)
    lo = math.inf
    hi = -math.inf
    t = math.radians(mount + angle)
    ct = math.cos(t)
    st = math.sin(t)
    for j in range(len(fk)):
        cx = ct * fcx[j] - st * fcy[j]  # the centre turns with the nozzle
        cy = st * fcx[j] + ct * fcy[j]
        phi = math.radians(mount + angle + frot[j])  # the orifice's own frame
        c = math.cos(phi)
        s = math.sin(phi)
        mid = cx * nx + cy * ny
        ux = c * nx + s * ny
        uy = -s * nx + c * ny
        if fk[j] == CONIC:
            half = hypot(fa[j] * ux, fb[j] * uy)
        else:
            half = abs(fa[j] * ux) + abs(fb[j] * uy)
        lo = min(lo, mid - half)
        hi = max(hi, mid + half)
    return hi - lo


@numba.njit(cache=True, nogil=True)
def pieces_of(group, rows, orifice, mount, turns, width, acc):  # pragma: no cover
    """The pieces the generator writes for one group of moves, and its running sums.

    ``group = (p0, p1, seg_len, angle, fold, split, lo, hi)``: move ``i`` (``p0[i] →
    p1[i]``, of length ``seg_len[i]``) is one piece at ``angle[i]`` (turning while it moves
    when ``fold[i]``), or, where ``split[i]``, the planner's pieces ``lo[i] … hi[i] - 1`` of
    ``rows = (t0, t1, angle)``. Each piece's bead width is the nozzle's across its
    direction (:func:`_bead_width` of the ``orifice`` mounted at ``mount``; ``width``
    when it does not ``turns``). ``acc = [extruded, layer length, layer dropped, last
    angle]`` is updated in the generator's order.

    Returns
    -------
    ax, ay, bx, by, phi, w, fold : ndarray
        Per piece, as :func:`printability.generate._emit_kernel.emit_pieces` takes them
        (:class:`~printability.generate._emit_kernel.Pieces`).
    """
    p0, p1, seg_len, angle, fold, split, lo, hi = group
    rt0, rt1, rphi = rows
    fk, fa, fb, fcx, fcy, frot = orifice
    n = len(p0)
    m = 0
    for i in range(n):
        m += hi[i] - lo[i] if split[i] else 1
    ax = np.empty(m)
    ay = np.empty(m)
    bx = np.empty(m)
    by = np.empty(m)
    phi = np.empty(m)
    w = np.empty(m)
    fo = np.empty(m)
    q = 0
    for i in range(n):
        x0 = p0[i, 0]
        y0 = p0[i, 1]
        dx = p1[i, 0] - x0
        dy = p1[i, 1] - y0
        acc[1] += seg_len[i]
        if split[i]:
            kept = 0.0
            for r in range(lo[i], hi[i]):
                kept += rt1[r] - rt0[r]
            acc[2] += seg_len[i] * (1 - kept)
            r0 = lo[i]
            r1 = hi[i]
        else:
            r0 = 0
            r1 = 1
        for r in range(r0, r1):
            if split[i]:
                t0 = rt0[r]
                t1 = rt1[r]
                a = rphi[r]
            else:
                t0 = 0.0
                t1 = 1.0
                a = angle[i]
            ax[q] = x0 + t0 * dx
            ay[q] = y0 + t0 * dy
            bx[q] = x0 + t1 * dx
            by[q] = y0 + t1 * dy
            direction = math.degrees(math.atan2(by[q] - ay[q], bx[q] - ax[q]))
            if turns:
                w[q] = _bead_width(direction, a, mount, fk, fa, fb, fcx, fcy, frot)
                phi[q] = a
                acc[3] = a
            else:
                w[q] = width
                phi[q] = math.nan
            fo[q] = abs(angle[i] - angle[i - 1]) if not split[i] and fold[i] else math.nan
            acc[0] += hypot(bx[q] - ax[q], by[q] - ay[q])
            q += 1
    return ax, ay, bx, by, phi, w, fo


def measures(footprints) -> bool:
    """Whether :func:`pieces_of` measures these footprints (conics and rectangles; the
    generator measures polygons in Python)."""
    return all(f.code in (CONIC, BOX) for f in footprints)


def orifice_of(footprints) -> Orifice:
    """The :class:`Orifice` of a nozzle's footprints (conics and rectangles:
    :func:`measures`)."""
    return Orifice(np.array([f.code for f in footprints], dtype=np.int64),
                   *(np.array(v, dtype=float) for v in zip(*[
                       (f.a, f.b, f.center[0], f.center[1], f.rotation) for f in footprints],
                       strict=True)))

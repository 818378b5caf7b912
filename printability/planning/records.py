"""The records the footprint kernels take: a few named groups of arrays, not dozens of them.

Each is a :class:`~typing.NamedTuple` of arrays and scalars, which numba passes to a
compiled function as one argument (its fields as they were: nothing is copied) and which
Python code still unpacks as a tuple. They are made once per call of a kernel, by
:mod:`printability.planning.footprints`, :mod:`printability.planning._boundary_grid`,
:mod:`printability.planning._point_location` and :mod:`printability.planning.beadunion`.

Conventions: coordinates and lengths in mm; orientations as cos/sin pairs; an empty
optional array (``Moves.scale``, ``Angles.k``, ``Groups.seg``/``gseg``) means "not used".
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["Angles", "BeadPolygons", "Beads", "BoundaryGrid", "CellGrid", "Directions",
           "Groups", "HalfPlanes", "Locator", "Moves", "Pieces"]


class CellGrid(NamedTuple):
    """Items binned on a uniform grid (CSR): cell ``c = iy·nx + ix`` (origin ``x0``, ``y0``,
    square cells of side ``cell``) lists the items ``items[start[c]:start[c + 1]]``
    (:func:`printability.planning._kernels.bin_boxes`)."""

    start: np.ndarray
    items: np.ndarray
    x0: float
    y0: float
    cell: float
    nx: int
    ny: int


class BoundaryGrid(NamedTuple):
    """The edges ``(ex0, ey0) → (ex1, ey1)`` of ∂G, binned on ``cells``; ``packed`` holds, per
    entry of ``cells.items``, its edge's ends as one row of 4
    (:func:`printability.planning._boundary_grid.boundary_grid`)."""

    ex0: np.ndarray
    ey0: np.ndarray
    ex1: np.ndarray
    ey1: np.ndarray
    cells: CellGrid
    packed: np.ndarray


class HalfPlanes(NamedTuple):
    """Convex polygons as half-planes ``ux·x + uy·y ≤ h``: polygon i's are ``off[i]:off[i + 1]``."""

    off: np.ndarray
    ux: np.ndarray
    uy: np.ndarray
    h: np.ndarray


class Beads(NamedTuple):
    """Beads: the segments ``(ax, ay) → (bx, by)`` and their polygons' side offsets ``rho``."""

    ax: np.ndarray
    ay: np.ndarray
    bx: np.ndarray
    by: np.ndarray
    rho: np.ndarray


class BeadPolygons(NamedTuple):
    """The bead polygons of :mod:`printability.planning.beadunion` (layout:
    :mod:`printability.planning._bead_polygons`): their half-planes ``planes``, corners ``vx``,
    ``vy`` (corner j ends edge j), (n, 4) boxes ``box``, edges per half turn ``k`` and the
    angle ``phase`` of their cap planes."""

    planes: HalfPlanes
    vx: np.ndarray
    vy: np.ndarray
    box: np.ndarray
    k: np.ndarray
    phase: np.ndarray


class Locator(NamedTuple):
    """What a point is located in G with: a bead union's ``polygons``, binned on ``cells``,
    and its ``beads`` (empty, ``polygons.off`` of length 1: the parity of ∂G's crossings)."""

    polygons: HalfPlanes
    cells: CellGrid
    beads: Beads


class Pieces(NamedTuple):
    """The nozzle's convex pieces that the kernels sweep: ``kind`` 0 ellipse, 1 rectangle,
    semi-axes ``a``, ``b`` (negative: mirrored), centre ``cx``, ``cy`` in the nozzle frame and
    rotation cos/sin ``rc``, ``rs``; one entry per piece."""

    kind: np.ndarray
    a: np.ndarray
    b: np.ndarray
    cx: np.ndarray
    cy: np.ndarray
    rc: np.ndarray
    rs: np.ndarray


class Moves(NamedTuple):
    """The segments swept: (n, 2) starts ``p0`` and ends ``p1``, and the footprint's
    ``scale`` per segment (empty: 1)."""

    p0: np.ndarray
    p1: np.ndarray
    scale: np.ndarray


class Angles(NamedTuple):
    """Orientations as cos/sin ``c0``, ``s0``; for a turning footprint the end orientation
    ``c1``, ``s1`` and the bulge factor ``k`` (all three empty: not turning)."""

    c0: np.ndarray
    s0: np.ndarray
    c1: np.ndarray
    s1: np.ndarray
    k: np.ndarray


class Directions(NamedTuple):
    """The base directions of a footprint's half-planes (cos ``cb``, sin ``sb``, before they
    are turned with the move), the sine ``det`` of the angle between neighbours, and the
    ``order`` the edge tests visit them in
    (:func:`printability.planning._covers.direction_order`)."""

    cb: np.ndarray
    sb: np.ndarray
    det: float
    order: np.ndarray


class Groups(NamedTuple):
    """Groups of candidates of :func:`~printability.planning._first_fits.first_fits`: group g
    tries the candidates ``gpos[g] … gend[g] - 1``, candidate q sweeping segment ``seg[q]``,
    or every candidate of group g segment ``gseg[g]`` when ``gseg`` is not empty."""

    seg: np.ndarray
    gseg: np.ndarray
    gpos: np.ndarray
    gend: np.ndarray

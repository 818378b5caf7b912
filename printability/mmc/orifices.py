"""The nozzle's orifices as safe polygons, and the lattice helpers of the sampling engines.

An :class:`Orifice` holds, in the nozzle frame, polygons inside and containing the true
orifice (and their convex pieces), an inscribed disk and the exact shape; the reference
engine (:mod:`printability.mmc.reference`) tests and places them, and the sampled engine
(:mod:`printability.mmc.sampled`, :mod:`printability.mmc._containment`,
:mod:`printability.mmc._sweeps`) places and checks them. :func:`angle_gap` and
:func:`grid_rectangles` describe the sampled angles and the lattice cells of P.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
import shapely.affinity
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from printability.model.geometry import rotation_matrix
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle
from printability.model.shapes import Footprint, convex_decomposition

__all__ = [
    "Orifice",
    "angle_gap",
    "cell_footprint_union",
    "grid_rectangles",
    "offset_orifice",
    "orifices_of",
]

# GEOS buffers approximate arcs by inscribed chords; dividing an offset by this factor
# makes a grown polygon contain (a shrunk one lie inside) the true offset set.
_ARC_QUAD_SEGS = 8
_ARC_FACTOR = 1.0 / math.cos(math.pi / (4 * _ARC_QUAD_SEGS))


@dataclass(frozen=True, eq=False)
class Orifice:
    """One orifice in the nozzle frame (mounting angle applied), with safe approximations.

    Attributes
    ----------
    inner, outer
        Polygons inside / containing the true orifice (equal for rectangles and
        polygons; curved orifices differ by about a·π²/(2n²) mm).
    inner_pieces, outer_pieces
        Convex pieces whose union is ``inner`` / ``outer`` (the polygon itself
        when convex, else a constrained triangulation).
    center, inradius
        A disk of that centre and radius (mm) lies inside ``inner``.
    circumradius
        Largest distance from ``center`` to ``outer``, mm.
    disk
        ``(cx, cy, r)`` when the orifice is an exact circle (tests are then exact).
    diameter
        Largest distance between two points of ``outer``, mm.
    shape, frame_angle
        The exact shape (:class:`~printability.model.shapes.Footprint`): its semi-axes (a, b)
        describe a circle/ellipse/rectangle centred on ``center`` and turned by
        ``frame_angle`` degrees in the nozzle frame (unused for polygons).
    """

    inner: Polygon
    outer: Polygon
    inner_pieces: tuple[Polygon, ...]
    outer_pieces: tuple[Polygon, ...]
    center: tuple[float, float]
    inradius: float
    circumradius: float
    disk: tuple[float, float, float] | None
    diameter: float
    shape: Footprint
    frame_angle: float = 0.0

    @property
    def semi_axes(self) -> tuple[float, float]:
        """(a, b) of the exact shape, mm (0 for polygons)."""
        return (self.shape.a, self.shape.b)


def orifices_of(nozzle: Nozzle, *, quad_segs: int) -> tuple[Orifice, ...]:
    """The orifices of ``nozzle`` with inner/outer polygons and inscribed disks.

    Parameters
    ----------
    nozzle
        The nozzle; its mounting angle is applied.
    quad_segs
        Vertices per quarter of a curved orifice.
    """
    out = []
    mount = nozzle.mount_angle
    rot = rotation_matrix(mount)
    for f in nozzle.footprints:
        inner = f.polygon(quad_segs=quad_segs, mode="inner")
        outer = f.polygon(quad_segs=quad_segs, mode="outer")
        if mount % 360.0:
            inner = shapely.affinity.rotate(inner, mount, origin=(0.0, 0.0))
            outer = shapely.affinity.rotate(outer, mount, origin=(0.0, 0.0))
        n = len(inner.exterior.coords) - 1
        r_in = f.inradius(n)
        if r_in is not None:
            c = tuple(float(v) for v in rot @ np.asarray(f.center))
        else:
            line = shapely.maximum_inscribed_circle(inner)
            (x0, y0), _ = line.coords
            c, r_in = (float(x0), float(y0)), float(line.length)
        disk = None if f.disk is None else (c[0], c[1], f.disk)
        pts = np.asarray(outer.exterior.coords)
        circum = float(np.max(np.hypot(pts[:, 0] - c[0], pts[:, 1] - c[1])))
        diff = pts[:, None, :] - pts[None, :, :]
        diameter = float(np.sqrt((diff**2).sum(-1).max()))
        out.append(Orifice(inner, outer, convex_decomposition(inner),
                           convex_decomposition(outer), c, r_in, circum, disk, diameter, f,
                           mount + f.rotation))
    return tuple(out)


def angle_gap(machine: Machine, angles: np.ndarray, period: float) -> tuple[float, bool]:
    """Largest gap between consecutive sampled angles (degrees) and whether they wrap.

    They wrap when the samples cover a whole symmetry period (full-turn machine or
    a range at least one period wide), so the last angle neighbours the first.
    """
    if len(angles) <= 1:
        return 0.0, False
    gaps = np.diff(angles)
    span = machine.angle_max - machine.angle_min
    wrap = machine.full_turn or (0 < period < 360.0 and span >= period - 1e-9)
    if wrap:
        gaps = np.append(gaps, angles[0] + min(period, 360.0) - angles[-1])
    return float(gaps.max()), bool(wrap)


def grid_rectangles(mask: np.ndarray, xs: np.ndarray, ys: np.ndarray, h: float) -> np.ndarray:
    """Cover the lattice cells of the True entries of ``mask[iy, ix]`` by few rectangles.

    Each True entry stands for the square of side ``h`` centred on (xs[ix], ys[iy]).
    Runs along rows are merged, then identical runs of consecutive rows.

    Returns
    -------
    ndarray (k, 4)
        Rectangles ``(x0, y0, x1, y1)``, mm.
    """
    rects: list[list[float]] = []
    open_runs: dict[tuple[int, int], int] = {}
    half = 0.5 * h
    for iy in range(mask.shape[0]):
        row = mask[iy]
        if not row.any():
            open_runs = {}
            continue
        d = np.diff(np.concatenate([[0], row.astype(np.int8), [0]]))
        starts = np.flatnonzero(d == 1)
        ends = np.flatnonzero(d == -1) - 1
        new_runs: dict[tuple[int, int], int] = {}
        for a, b in zip(starts.tolist(), ends.tolist(), strict=True):
            k = open_runs.get((a, b))
            if k is not None:
                rects[k][3] = ys[iy] + half
            else:
                k = len(rects)
                rects.append([xs[a] - half, ys[iy] - half, xs[b] + half, ys[iy] + half])
            new_runs[(a, b)] = k
        open_runs = new_runs
    return np.asarray(rects, dtype=float).reshape(-1, 4)


def cell_footprint_union(
    rects: np.ndarray, pieces: tuple[Polygon, ...], angle: float, *, grow: float = 0.0
) -> list[BaseGeometry]:
    """Polygons whose union is ∪_rect rect ⊕ R(angle)·(∪ pieces ⊕ D(grow)).

    Each rectangle ⊕ convex piece is the convex hull of the piece placed at the four
    corners (exact for convex pieces). ``grow`` > 0 buffers each piece first
    (enlarged so the chords of the buffer stay outside the true offset).
    """
    if len(rects) == 0:
        return []
    out: list[BaseGeometry] = []
    rot = rotation_matrix(angle)
    corners = np.stack([rects[:, [0, 1]], rects[:, [2, 1]], rects[:, [2, 3]],
                        rects[:, [0, 3]]], axis=1)  # (k, 4, 2)
    for piece in pieces:
        if grow > 0:
            piece = piece.buffer(grow * _ARC_FACTOR, quad_segs=_ARC_QUAD_SEGS)
        v = np.asarray(piece.exterior.coords)[:-1] @ rot.T  # (nv, 2)
        pts = (corners[:, :, None, :] + v[None, None, :, :]).reshape(len(rects), -1, 2)
        out.extend(shapely.convex_hull(shapely.linestrings(pts)).tolist())
    return out


def offset_orifice(o: Orifice, base: str, offset: float) -> BaseGeometry:
    """The orifice's ``base`` ("inner" or "outer") polygon offset by ``offset`` mm.

    Outward (``offset`` > 0) the result contains the true offset set, inward it lies
    inside the true erosion: convex polygons use mitred joins (exact inward, a
    superset by offset·(sec(θ/2) − 1) at a vertex of exterior angle θ outward);
    other polygons use round joins with the radius enlarged so the chords of the
    arcs stay on the safe side. May be empty when shrunk.
    """
    poly = o.inner if base == "inner" else o.outer
    if not offset:
        return poly
    convex = len(o.inner_pieces if base == "inner" else o.outer_pieces) == 1
    if convex:
        return poly.buffer(offset, join_style="mitre", mitre_limit=1e3)
    return poly.buffer(offset * _ARC_FACTOR, quad_segs=_ARC_QUAD_SEGS)

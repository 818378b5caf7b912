"""Planar geometry types and the conventions every module follows.

Conventions (each has a test in ``tests/core/test_conventions.py``)
-------------------------------------------------------------------
Units
    Lengths in millimetres, areas in mm², volumes in mm³, angles in
    **degrees**, positive counter-clockwise about +Z (looking down on the
    bed). Radians never cross a public boundary.
Nozzle frame and origin
    A nozzle footprint A⁰ is given in its own frame. Its origin (0, 0) is the
    point the machine positions (the X/Y the G-code names) and the axis the
    rotary joint turns about. An offset nozzle simply has a footprint that does
    not contain its origin.
Placed nozzle
    For the separable machines (XY, T-T-R) a configuration is u = (t, φ) and
    the placed footprint is A^u = R(φ)·A⁰ + t.
Motion restriction and reflection
    P_φ = {t : R(φ)A⁰ + t ⊆ G} = G ⊖ R(φ)A⁰ (erosion *without* reflection).
    Computed as a Minkowski sum it reads P_φ = complement(Gᶜ ⊕ (−R(φ)A⁰)):
    the reflected footprint −A appears only there. The as-built layer is
    S = ∪_φ (P_φ ⊕ R(φ)A⁰), i.e. the union of morphological openings.
Raster grids and array axis order
    A :class:`Grid` has origin (x0, y0) at the *lower-left corner* of pixel
    [0, 0], square pixels of side ``h``, ``ny`` rows and ``nx`` columns.
    Arrays are indexed ``[row, col] = [iy, ix]``; row index grows with **y**
    (row 0 is at the bottom, not the top as in image files). Pixel [i, j]
    covers [x0 + j·h, x0 + (j+1)·h] × [y0 + i·h, y0 + (i+1)·h]; its centre is
    (x0 + (j+½)h, y0 + (i+½)h). Stacks over angles put the angle first:
    ``[k, iy, ix]``.
Regions
    A layer's target G is a shapely (Multi)Polygon with holes allowed, made
    valid by :func:`as_region` (which repairs or refuses).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.base import BaseGeometry

from printability.errors import FileFormatError, InputError, ResourceError

__all__ = [
    "MAX_COORDINATE",
    "Grid",
    "Raster",
    "as_region",
    "check_coordinates",
    "polygons_of",
    "rotation_matrix",
]


def rotation_matrix(angle_deg: float) -> np.ndarray:
    """2×2 matrix of the counter-clockwise rotation by ``angle_deg`` degrees."""
    a = np.deg2rad(angle_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s], [s, c]])


def polygons_of(geom: BaseGeometry) -> list[Polygon]:
    """The non-empty polygons of any geometry (collections flattened, lines dropped)."""
    out: list[Polygon] = []
    for part in shapely.get_parts(geom):
        if isinstance(part, Polygon):
            if not part.is_empty:
                out.append(part)
        elif hasattr(part, "geoms"):
            out.extend(polygons_of(part))
    return out


def as_region(
    geom: Any,
    *,
    name: str = "region",
    repair: bool = True,
    min_area: float = 0.0,
) -> MultiPolygon:
    """Validate a layer target G and return it as a MultiPolygon.

    Parameters
    ----------
    geom
        A shapely geometry (Polygon, MultiPolygon, GeometryCollection) or
        anything :func:`shapely.geometry.shape` accepts.
    name
        How the region is named in error messages (file and layer, say).
    repair
        Repair an invalid geometry (self-intersections, bow-ties) with
        :func:`shapely.make_valid`; when False an invalid input is refused.
    min_area
        Polygons smaller than this (mm²) are dropped.

    Raises
    ------
    InputError
        Empty region, non-finite coordinates, or an invalid one with
        ``repair=False``.
    """
    if not isinstance(geom, BaseGeometry):
        try:
            geom = shapely.geometry.shape(geom)
        except Exception as exc:  # shapely raises several unrelated types
            raise InputError(f"{name}: expected a polygonal geometry; got {type(geom).__name__}"
                             f" ({exc})") from None
    if geom.is_empty:
        raise InputError(f"{name}: the region is empty; expected at least one polygon "
                         "with positive area")
    coords = shapely.get_coordinates(geom)
    if not np.isfinite(coords).all():
        raise InputError(f"{name}: the region has non-finite coordinates (NaN or infinity)")
    if not geom.is_valid:
        if not repair:
            reason = shapely.is_valid_reason(geom)
            raise InputError(f"{name}: the region is not a valid polygon ({reason}); "
                             "pass repair=True to repair it")
        geom = shapely.make_valid(geom)
    polys = [p for p in polygons_of(geom) if p.area > min_area]
    if not polys:
        raise InputError(f"{name}: the region has no area (only lines or points, or "
                         f"polygons below {min_area} mm²)")
    merged = shapely.union_all(polys) if len(polys) > 1 else polys[0]
    parts = polygons_of(merged)
    return MultiPolygon(parts)


@dataclass(frozen=True)
class Grid:
    """A regular square grid: origin at the lower-left corner, spacing ``h`` mm.

    See the module docstring for the axis order.
    """

    x0: float
    y0: float
    h: float
    nx: int
    ny: int

    def __post_init__(self) -> None:
        if not (self.h > 0) or self.nx < 1 or self.ny < 1:
            raise InputError(f"invalid grid: spacing {self.h} mm, {self.nx}×{self.ny} pixels")

    @property
    def shape(self) -> tuple[int, int]:
        """``(ny, nx)``: the shape of arrays on this grid."""
        return (self.ny, self.nx)

    @property
    def pixel_area(self) -> float:
        return self.h * self.h

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return (self.x0, self.y0, self.x0 + self.nx * self.h, self.y0 + self.ny * self.h)

    def centers(self) -> tuple[np.ndarray, np.ndarray]:
        """1-D arrays of pixel-centre x (length nx) and y (length ny), mm."""
        xs = self.x0 + (np.arange(self.nx) + 0.5) * self.h
        ys = self.y0 + (np.arange(self.ny) + 0.5) * self.h
        return xs, ys

    @classmethod
    def covering(
        cls,
        bounds: tuple[float, float, float, float],
        h: float,
        *,
        margin: float = 0.0,
        max_pixels: int | None = None,
    ) -> Grid:
        """The grid of spacing ``h`` covering ``bounds`` grown by ``margin``.

        The origin is snapped to a multiple of ``h`` so grids built for
        different layers of one part line up.

        Raises
        ------
        ResourceError
            If the grid would have more than ``max_pixels`` pixels.
        """
        if not (h > 0):
            raise InputError(f"resolution must be a positive length in mm; got {h!r}")
        minx, miny, maxx, maxy = bounds
        x0 = np.floor((minx - margin) / h) * h
        y0 = np.floor((miny - margin) / h) * h
        nx = int(np.ceil((maxx + margin - x0) / h)) or 1
        ny = int(np.ceil((maxy + margin - y0) / h)) or 1
        if max_pixels is not None and nx * ny > max_pixels:
            raise ResourceError(
                f"a grid of spacing {h} mm over {maxx - minx:.3g} × {maxy - miny:.3g} mm needs "
                f"{nx} × {ny} = {nx * ny:,} pixels, more than the {max_pixels:,} allowed by the "
                "memory limit; use a coarser resolution or raise Settings.max_memory"
            )
        return cls(float(x0), float(y0), float(h), nx, ny)


@dataclass(frozen=True, eq=False)
class Raster:
    """An array on a :class:`Grid`. ``data.shape`` ends with ``grid.shape``.

    A leading axis (angles, say) is allowed: ``data.shape == (k, ny, nx)``.
    """

    grid: Grid
    data: np.ndarray

    def __post_init__(self) -> None:
        if tuple(self.data.shape[-2:]) != self.grid.shape:
            raise InputError(
                f"raster data of shape {self.data.shape} does not end with the grid shape "
                f"{self.grid.shape}"
            )

    def area(self) -> float:
        """Sum of the data times the pixel area (meaningful for boolean masks), mm²."""
        return float(np.count_nonzero(self.data)) * self.grid.pixel_area


# --------------------------------------------------------------------------- input coordinates

#: Largest coordinate a drawing or map may hold (in its own units): beyond, areas and buffers
#: lose every digit (1e308 overflows them); no part or map comes near it.
MAX_COORDINATE = 1e15


def check_coordinates(path: object, coords: np.ndarray, *, element: str | None = None) -> None:
    """Refuse coordinates that are not finite or beyond :data:`MAX_COORDINATE`."""
    a = np.asarray(coords, dtype=float)
    bad = ~(np.abs(a) <= MAX_COORDINATE)
    if bad.any():
        v = a[bad].flat[0]
        what = "out of range" if np.isfinite(v) else "not finite"
        raise FileFormatError(path, f"a coordinate is {what} ({v:g}); expected finite numbers "
                              f"up to {MAX_COORDINATE:g}", element=element)

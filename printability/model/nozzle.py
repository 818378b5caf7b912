"""Nozzles and the nozzle SPEC syntax.

A :class:`Nozzle` is one or several orifices (:class:`~printability.model.shapes.Footprint`, one
type per shape) fixed on one carriage, given in the nozzle frame (origin = the point the
machine positions and the axis the rotary joint turns about; see
:mod:`printability.model.geometry`).

SPEC syntax (docs/design.md §4), parsed by :func:`parse_nozzle` from the shapes in
:data:`printability.model.shapes.SHAPES` (named in :data:`printability.options.NOZZLE_KINDS`)::

    circle:d=0.4                  round, diameter 0.4 mm (or r=0.2)
    ellipse:major=0.8,minor=0.3   full axis lengths; major along the nozzle x axis
    rect:w=0.8,h=0.3              w along x, h along y
    polygon:FILE.svg              outline from a file (.svg, .wkt, .txt/.csv "x y" lines)
    polygon:pts=0 0;1 0;1 0.3     inline vertices

Common parameters: ``x=``, ``y=`` offset the orifice from the origin (mm),
``rot=`` turns the orifice in the nozzle frame (degrees), ``angle=`` the
mounting angle of the whole nozzle (degrees), ``scale=`` scales a polygon,
``origin=centroid`` moves a polygon's origin to its centroid. Several
orifices on one head are joined with ``+``:
``circle:d=0.4,x=-10+circle:d=0.4,x=10``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely.affinity
from shapely.geometry import MultiPolygon
from shapely.geometry.base import BaseGeometry

from printability.errors import InputError, excerpt
from printability.model.shapes import (
    COMMON_PARAMETERS,
    NOZZLE_SIZE_RANGE,
    SHAPES,
    Footprint,
    number,
)
from printability.options import NOZZLE_KINDS

__all__ = ["NOZZLE_SIZE_RANGE", "Footprint", "Nozzle", "parse_nozzle"]


@dataclass(frozen=True)
class Nozzle:
    """A nozzle: one or more orifices that move together, plus a mounting angle.

    ``outline(angle)`` is R(mount_angle + angle)·A⁰ in the machine frame at the
    origin (see :mod:`printability.model.geometry` for the conventions).
    """

    spec: str
    footprints: tuple[Footprint, ...]
    mount_angle: float = 0.0
    params: Mapping[str, float] = field(default_factory=dict, compare=False, repr=False)

    @property
    def kind(self) -> str:
        """The orifice kind, or ``"multi"`` for a head with several orifices."""
        return self.footprints[0].kind if len(self.footprints) == 1 else "multi"

    @property
    def area(self) -> float:
        """Total orifice area, mm²."""
        return float(sum(f.area for f in self.footprints))

    @property
    def radius(self) -> float:
        """Largest distance from the origin to any point of any orifice, mm.

        A rotation by Δφ moves no nozzle point by more than radius·Δφ (radians).
        """
        return max(f.radius for f in self.footprints)

    @property
    def is_round(self) -> bool:
        """True for one circular orifice centred on the rotation axis."""
        f = self.footprints[0]
        return len(self.footprints) == 1 and f.disk is not None and f.center == (0.0, 0.0)

    @property
    def symmetry_period(self) -> float:
        """Smallest angle (degrees) after which the outline repeats; 0 for a round nozzle.

        360 means no symmetry is exploited (offset or multi-orifice nozzles, polygons).
        """
        if self.is_round:
            return 0.0
        if len(self.footprints) == 1 and self.footprints[0].center == (0.0, 0.0):
            return self.footprints[0].symmetry
        return 360.0

    @property
    def min_width(self) -> float:
        """Narrowest bead (width across the motion) the nozzle can lay, mm."""
        return min(self.bead_width(d) for d in np.arange(0.0, 180.0, 0.5))

    @property
    def max_width(self) -> float:
        """Widest bead the nozzle can lay, mm."""
        return max(self.bead_width(d) for d in np.arange(0.0, 180.0, 0.5))

    def outline(
        self, angle: float = 0.0, *, quad_segs: int = 32, mode: str = "inner"
    ) -> BaseGeometry:
        """The footprint turned by ``angle`` degrees (plus the mounting angle).

        Returns a Polygon for one orifice, a MultiPolygon for several.
        """
        polys = [f.polygon(quad_segs=quad_segs, mode=mode) for f in self.footprints]
        total = self.mount_angle + angle
        if total % 360.0:
            polys = [shapely.affinity.rotate(p, total, origin=(0.0, 0.0)) for p in polys]
        return polys[0] if len(polys) == 1 else MultiPolygon(polys)

    def bead_width(self, direction: float, angle: float = 0.0) -> float:
        """Width of the swept bead when moving along ``direction`` (degrees).

        The extent of the footprint (turned by ``angle``) across the motion,
        i.e. its projection on the normal of the direction, mm. Exact for
        circles, ellipses, rectangles and polygons.
        """
        theta = math.radians(direction)
        nx, ny = -math.sin(theta), math.cos(theta)
        lo, hi = math.inf, -math.inf
        for f in self.footprints:
            f_lo, f_hi = f.span(nx, ny, self.mount_angle + angle)
            lo, hi = min(lo, f_lo), max(hi, f_hi)
        return float(hi - lo)

    def bead_widths(self, direction: np.ndarray, angle: np.ndarray) -> np.ndarray:
        """:meth:`bead_width` of many moves at once (arrays of degrees, broadcast).

        The same formulas elementwise (numpy's trigonometry may differ from
        :mod:`math`'s in the last bit). Cost: O(n) per orifice (O(n·v) for a
        polygon of v vertices).
        """
        theta = np.radians(np.asarray(direction, dtype=float))
        ang = np.asarray(angle, dtype=float)
        theta, ang = np.broadcast_arrays(theta, ang)
        nx, ny = -np.sin(theta), np.cos(theta)
        lo = np.full(theta.shape, np.inf)
        hi = np.full(theta.shape, -np.inf)
        for f in self.footprints:
            f_lo, f_hi = f.spans(nx, ny, self.mount_angle + ang)
            lo = np.minimum(lo, f_lo)
            hi = np.maximum(hi, f_hi)
        return hi - lo

    def convex_pieces(self) -> tuple[Footprint, ...]:
        """Convex orifices in the nozzle frame, mounting angle applied, whose union is the
        nozzle's footprint exactly (one per circle, ellipse, rectangle or convex polygon; a
        non-convex polygon's triangles)."""
        m = self.mount_angle
        return tuple(piece for f in self.footprints for piece in f.turned(m).convex_pieces())


# --------------------------------------------------------------------------- parsing

def _parse_part(part: str, spec: str, base_dir: Path | None) -> tuple[Footprint, float | None]:
    kind, _, rest = part.partition(":")
    shape = SHAPES[NOZZLE_KINDS.check(kind)]
    allowed = shape.parameters | COMMON_PARAMETERS
    params: dict[str, str] = {}
    if "file" in shape.parameters and rest and "=" not in rest.split(",", 1)[0]:
        first, _, rest = rest.partition(",")
        params["file"] = first
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, value = item.partition("=")
        key = key.strip().lower()
        if not eq:
            raise InputError(f"nozzle spec {excerpt(spec)}: expected key=value; "
                             f"found {excerpt(item)}")
        if key not in allowed:
            raise InputError(
                f"nozzle spec {excerpt(spec)}: unknown parameter {excerpt(key)} for a "
                f"{shape.kind}; expected one of: {', '.join(sorted(allowed))}"
            )
        if key in params:
            raise InputError(f"nozzle spec {excerpt(spec)}: parameter {excerpt(key)} given twice")
        params[key] = value.strip()
    num = {k: number(spec, k, v) for k, v in params.items()
           if k not in ("file", "pts", "origin")}
    return shape.from_spec(spec, num, params, base_dir=base_dir), num.get("angle")


def parse_nozzle(spec: str | Nozzle, *, base_dir: str | Path | None = None) -> Nozzle:
    """Parse a nozzle SPEC (see the module docstring).

    Parameters
    ----------
    spec
        The SPEC string, or an existing :class:`Nozzle` (returned unchanged).
    base_dir
        Directory that relative polygon file names are resolved against.

    Raises
    ------
    UnknownOptionError
        The kind is not one of :data:`printability.options.NOZZLE_KINDS`.
    InputError
        A parameter is missing, unknown, not a number, zero or negative.
    """
    if isinstance(spec, Nozzle):
        return spec
    if not isinstance(spec, str) or not spec.strip():
        raise InputError(f"nozzle spec must be a non-empty string such as 'circle:d=0.4'; "
                         f"found {spec!r}")
    text = spec.strip()
    base = Path(base_dir) if base_dir is not None else None
    footprints = []
    mount: float | None = None
    for part in text.split("+"):
        fp, angle = _parse_part(part.strip(), text, base)
        if angle is not None:
            if mount is not None and not math.isclose(mount, angle):
                raise InputError(f"nozzle spec {excerpt(text)}: conflicting angle= values "
                                 f"({mount:g} and {angle:g})")
            mount = angle
        footprints.append(fp)
    return Nozzle(text, tuple(footprints), mount or 0.0)

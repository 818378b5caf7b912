"""Orifice shapes: one type per shape, owning its geometry.

A :class:`Footprint` is one orifice in the nozzle frame (see :mod:`printability.model.geometry`
for the frame and angle conventions). Each shape is a subclass that answers every question
the engines ask of an orifice, so no engine compares shape names:

========================  ==========================================================
``area``, ``radius``      exact area (mm²), reach from the rotation axis (mm)
``polygon(mode=)``        inner / outer polygonal approximation (exact for polygons)
``half_width(ux, uy)``    half the bead width across a unit normal given in the
                          orifice's own frame (``half_widths`` for arrays)
``support(ux, uy)``       support function of the orifice in the nozzle frame
``symmetry``              period (degrees) of the shape about its own centre
``inradius(n)``           a disk about the centre inside the n-vertex inner polygon
``eroded(d)``             semi-axes of a same-kind shape inside the erosion by d mm
``disk``                  radius when the orifice is an exact circle
``convex_pieces()``       convex shapes whose union is the orifice, exactly
``turned(deg)``           the orifice turned about the nozzle origin
``code``                  the compiled kernels' shape code (:data:`CONIC`, :data:`BOX`,
                          :data:`POLYGON`)
========================  ==========================================================

To add a shape: a subclass here registered in :data:`SHAPES` (its SPEC parameters and
:meth:`Footprint.from_spec`), and its name in :data:`printability.options.NOZZLE_KINDS`.
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import ClassVar

import numpy as np
import shapely
import shapely.affinity
from shapely.geometry import Polygon

from printability.errors import FileFormatError, InputError, PrintabilityOSError, excerpt
from printability.model.geometry import (
    MAX_COORDINATE,
    check_coordinates,
    polygons_of,
    rotation_matrix,
)

__all__ = ["BOX", "CONIC", "NOZZLE_SIZE_RANGE", "POLYGON", "SHAPES", "Circle", "Ellipse",
           "Footprint", "PolygonOrifice", "Rect", "convex_decomposition", "number"]

#: The compiled kernels' shape codes: an affine image of a disk (circle, ellipse), an
#: axis-aligned box in the orifice frame (rectangle), a polygon given by its vertices.
CONIC, BOX, POLYGON = 0, 1, 2

#: Orifice sizes a nozzle may have, mm: a micrometre to a metre (below, the analysis's
#: grids and footprints overflow; above, no printer).
NOZZLE_SIZE_RANGE = (1e-3, 1e3)

_OUTLINE_MODES = ("inner", "outer")
_NUMBER = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$")
#: SPEC parameters every shape takes: offset, rotation in the nozzle frame, mounting angle.
COMMON_PARAMETERS = frozenset({"x", "y", "rot", "angle"})


def convex_decomposition(poly: Polygon) -> tuple[Polygon, ...]:
    """``poly`` as convex polygons whose union is exactly ``poly``.

    The polygon itself when it is convex (its hull exceeds it by at most 10⁻¹² of its area),
    else its constrained Delaunay triangulation. Cost O(n log n) for n vertices.
    """
    if poly.convex_hull.area - poly.area <= 1e-12 * max(poly.area, 1e-300):
        return (poly,)
    return tuple(polygons_of(shapely.constrained_delaunay_triangles(poly)))


@dataclass(frozen=True)
class Footprint:
    """One orifice in the nozzle frame; a subclass per shape.

    Attributes
    ----------
    a, b
        Semi-axes (mm): circle a = b = r; ellipse a = semi-major along the orifice's
        x axis, b = semi-minor; rectangle a = w/2, b = h/2. 0 for polygons.
    center
        Position of the orifice centre in the nozzle frame, mm.
    rotation
        Orientation of the orifice in the nozzle frame, degrees.
    vertices
        Polygon shell vertices in the nozzle frame (polygons only; centre and rotation
        already applied), as a tuple of (x, y).
    """

    a: float = 0.0
    b: float = 0.0
    center: tuple[float, float] = (0.0, 0.0)
    rotation: float = 0.0
    vertices: tuple[tuple[float, float], ...] = ()

    #: The shape's name in a nozzle SPEC and in reports.
    kind: ClassVar[str] = ""
    #: The compiled kernels' code for the shape (:data:`CONIC`, :data:`BOX`, :data:`POLYGON`).
    code: ClassVar[int] = POLYGON
    #: True for an affine image of a disk (given by ``a``, ``b``, ``rotation``).
    conic: ClassVar[bool] = False
    #: Parameters of the SPEC, besides :data:`COMMON_PARAMETERS`.
    parameters: ClassVar[frozenset[str]] = frozenset()

    # ----------------------------------------------------------------- measures
    @property
    def area(self) -> float:
        """Exact area, mm²."""
        raise NotImplementedError

    @property
    def radius(self) -> float:
        """Largest distance from the nozzle origin to a point of the orifice, mm."""
        return float(np.max(np.hypot(*self.coords(0).T)))

    @property
    def symmetry(self) -> float:
        """Smallest turn about the orifice's own centre (degrees) that maps it onto itself;
        360 when none is exploited."""
        return 360.0

    @property
    def disk(self) -> float | None:
        """The radius when the orifice is an exact circle, else None."""
        return None

    def inradius(self, n: int) -> float | None:
        """Radius of a disk about :attr:`center` inside the ``n``-vertex inner polygon, or
        None when the shape has no such closed form (polygons: use the polygon's own)."""
        return None

    def eroded(self, shrink: float) -> tuple[float, float] | None:
        """Semi-axes of a shape of the same kind lying inside this one eroded by ``shrink``
        mm, or None when the shape has no such closed form (polygons)."""
        return None

    # ----------------------------------------------------------------- outlines
    def local_coords(self, n_quarter: int) -> np.ndarray:
        """Vertices (k, 2) in the orifice's own frame (curves: 4·n_quarter points, at
        least 8)."""
        raise NotImplementedError

    def coords(self, n_quarter: int) -> np.ndarray:
        """Vertices (k, 2) in the nozzle frame; curves inscribed with 4·n_quarter points."""
        return self.local_coords(n_quarter) @ rotation_matrix(self.rotation).T \
            + np.asarray(self.center)

    def polygon(self, *, quad_segs: int = 32, mode: str = "inner") -> Polygon:
        """Polygonal approximation in the nozzle frame.

        ``mode="inner"``: vertices on the curve (contained in the true orifice);
        ``mode="outer"``: the same polygon scaled about the centre by 1/cos(π/n) so it
        contains the true ellipse (n vertices). Both are exact for rectangles and
        polygons. The Hausdorff error of either is at most a·(1/cos(π/n) − 1) ≈
        a·π²/(2n²).
        """
        if mode not in _OUTLINE_MODES:
            raise InputError(f"unknown outline mode {mode!r}; expected one of: inner, outer")
        coords = self.coords(quad_segs)
        if mode == "outer" and self.conic:
            n = len(coords)
            c = np.asarray(self.center)
            coords = c + (coords - c) / math.cos(math.pi / n)
        return Polygon(coords)

    # ----------------------------------------------------------------- widths and support
    def half_width(self, ux: float, uy: float) -> float:
        """Half the extent across the unit normal (ux, uy) given in the orifice's own frame,
        about its centre (conics and boxes; :mod:`math`)."""
        raise NotImplementedError

    def half_widths(self, ux: np.ndarray, uy: np.ndarray) -> np.ndarray:
        """:meth:`half_width` of arrays of normals (numpy: may differ from :mod:`math` in
        the last bit)."""
        raise NotImplementedError

    def span(self, nx: float, ny: float, turn: float) -> tuple[float, float]:
        """Least and greatest of u·x over the orifice turned by ``turn`` degrees about the
        nozzle origin, for the unit vector u = (nx, ny) in the machine frame, mm."""
        t = math.radians(turn)
        ct, st = math.cos(t), math.sin(t)
        cx, cy = self.center
        mid = (ct * cx - st * cy) * nx + (st * cx + ct * cy) * ny
        phi = math.radians(turn + self.rotation)
        c, s = math.cos(phi), math.sin(phi)
        half = self.half_width(c * nx + s * ny, -s * nx + c * ny)  # the normal in its frame
        return mid - half, mid + half

    def spans(self, nx: np.ndarray, ny: np.ndarray,
              turn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`span` elementwise (arrays of the same shape; numpy's trigonometry)."""
        t = np.radians(turn)
        ct, st = np.cos(t), np.sin(t)
        cx, cy = self.center
        mid = (ct * cx - st * cy) * nx + (st * cx + ct * cy) * ny
        phi = np.radians(turn + self.rotation)
        c, s = np.cos(phi), np.sin(phi)
        half = self.half_widths(c * nx + s * ny, -s * nx + c * ny)
        return mid - half, mid + half

    def support(self, ux: np.ndarray, uy: np.ndarray) -> np.ndarray:
        """Support function h(u) = max over the orifice of u·x, for arrays of unit vectors
        (ux, uy) in the nozzle frame."""
        raise NotImplementedError

    # ----------------------------------------------------------------- pieces
    def convex_pieces(self) -> tuple[Footprint, ...]:
        """Convex orifices whose union is this one, exactly."""
        return (self,)

    def turned(self, angle: float) -> Footprint:
        """This orifice turned by ``angle`` degrees about the nozzle origin."""
        r = math.radians(angle)
        c, s = math.cos(r), math.sin(r)
        cx, cy = self.center
        return replace(self, center=(c * cx - s * cy, s * cx + c * cy),
                       rotation=self.rotation + angle)

    # ----------------------------------------------------------------- SPEC
    @classmethod
    def from_spec(cls, spec: str, num: Mapping[str, float], params: Mapping[str, str], *,
                  base_dir: Path | None) -> Footprint:
        """The orifice of one ``+``-separated part of a SPEC: ``num`` holds the numeric
        parameters, ``params`` every parameter as text; ``base_dir`` resolves files."""
        raise NotImplementedError


@dataclass(frozen=True)
class Ellipse(Footprint):
    """An elliptical orifice: semi-major ``a`` along its own x axis, semi-minor ``b``."""

    kind: ClassVar[str] = "ellipse"
    code: ClassVar[int] = CONIC
    conic: ClassVar[bool] = True
    parameters: ClassVar[frozenset[str]] = frozenset({"major", "minor"})

    @property
    def area(self) -> float:
        return math.pi * self.a * self.b

    @property
    def radius(self) -> float:
        return math.hypot(*self.center) + self.a

    @property
    def symmetry(self) -> float:
        return 180.0

    def inradius(self, n: int) -> float:
        # the inscribed n-gon is the affine image of a regular n-gon, which holds the disk
        # of radius cos(π/n)
        return min(self.a, self.b) * math.cos(math.pi / n)

    def eroded(self, shrink: float) -> tuple[float, float]:
        # E(ka, kb) with k = 1 − shrink/b lies inside the ellipse eroded by ``shrink``
        k = 1.0 - shrink / self.b
        return self.a * k, self.b * k

    def local_coords(self, n_quarter: int) -> np.ndarray:
        n = max(4 * n_quarter, 8)
        t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
        return np.column_stack([self.a * np.cos(t), self.b * np.sin(t)])

    def half_width(self, ux: float, uy: float) -> float:
        return math.hypot(self.a * ux, self.b * uy)

    def half_widths(self, ux: np.ndarray, uy: np.ndarray) -> np.ndarray:
        return np.hypot(self.a * ux, self.b * uy)

    def support(self, ux: np.ndarray, uy: np.ndarray) -> np.ndarray:
        cx, cy = self.center
        r = math.radians(self.rotation)
        c, s = math.cos(r), math.sin(r)
        vx = c * ux + s * uy  # u in the orifice's own axes
        vy = -s * ux + c * uy
        return ux * cx + uy * cy + np.sqrt((self.a * vx) ** 2 + (self.b * vy) ** 2)

    @classmethod
    def from_spec(cls, spec, num, params, *, base_dir):
        for k in ("major", "minor"):
            if k not in num:
                raise InputError(f"nozzle spec {excerpt(spec)}: an ellipse needs {k}= "
                                 "(full axis, mm)")
            positive(spec, k, num[k])
        if num["minor"] > num["major"]:
            raise InputError(
                f"nozzle spec {excerpt(spec)}: minor ({num['minor']:g}) is larger than major "
                f"({num['major']:g}); swap them or use rot=90"
            )
        return cls(num["major"] / 2, num["minor"] / 2, _center(num), num.get("rot", 0.0))


@dataclass(frozen=True)
class Circle(Ellipse):
    """A round orifice of radius ``a`` (= ``b``)."""

    kind: ClassVar[str] = "circle"
    parameters: ClassVar[frozenset[str]] = frozenset({"d", "r"})

    @property
    def disk(self) -> float:
        return self.a

    @property
    def symmetry(self) -> float:
        # Turning a circle about its centre changes nothing; a nozzle whose circle is off
        # the rotation axis is handled by :attr:`Nozzle.symmetry_period`.
        return 180.0

    @classmethod
    def from_spec(cls, spec, num, params, *, base_dir):
        if ("d" in num) == ("r" in num):
            raise InputError(f"nozzle spec {excerpt(spec)}: a circle needs exactly one of d= or r=")
        r = num["d"] / 2 if "d" in num else num["r"]
        positive(spec, "the diameter", 2 * r)
        return cls(r, r, _center(num), 0.0)


@dataclass(frozen=True)
class Rect(Footprint):
    """A rectangular orifice of half-sides ``a`` (along its own x axis) and ``b``."""

    kind: ClassVar[str] = "rect"
    code: ClassVar[int] = BOX
    parameters: ClassVar[frozenset[str]] = frozenset({"w", "h"})

    @property
    def area(self) -> float:
        return 4.0 * self.a * self.b

    @property
    def symmetry(self) -> float:
        return 90.0 if math.isclose(self.a, self.b) else 180.0

    def inradius(self, n: int) -> float:
        return min(self.a, self.b)

    def eroded(self, shrink: float) -> tuple[float, float]:
        return self.a - shrink, self.b - shrink  # exact erosion of a rectangle

    def local_coords(self, n_quarter: int) -> np.ndarray:
        return np.array([[self.a, self.b], [-self.a, self.b],
                         [-self.a, -self.b], [self.a, -self.b]])

    def half_width(self, ux: float, uy: float) -> float:
        return abs(self.a * ux) + abs(self.b * uy)

    def half_widths(self, ux: np.ndarray, uy: np.ndarray) -> np.ndarray:
        return np.abs(self.a * ux) + np.abs(self.b * uy)

    def support(self, ux: np.ndarray, uy: np.ndarray) -> np.ndarray:
        cx, cy = self.center
        r = math.radians(self.rotation)
        c, s = math.cos(r), math.sin(r)
        vx = c * ux + s * uy
        vy = -s * ux + c * uy
        return ux * cx + uy * cy + self.a * np.abs(vx) + self.b * np.abs(vy)

    @classmethod
    def from_spec(cls, spec, num, params, *, base_dir):
        for k in ("w", "h"):
            if k not in num:
                raise InputError(f"nozzle spec {excerpt(spec)}: a rectangle needs {k}= (mm)")
            positive(spec, k, num[k])
        return cls(num["w"] / 2, num["h"] / 2, _center(num), num.get("rot", 0.0))


@dataclass(frozen=True)
class PolygonOrifice(Footprint):
    """An orifice given by its shell's vertices in the nozzle frame (``vertices``)."""

    kind: ClassVar[str] = "polygon"
    parameters: ClassVar[frozenset[str]] = frozenset({"file", "pts", "scale", "origin"})

    @cached_property
    def points(self) -> np.ndarray:
        """The vertices as a read-only (k, 2) array."""
        v = np.asarray(self.vertices, dtype=float)
        v.setflags(write=False)
        return v

    @property
    def area(self) -> float:
        return Polygon(self.vertices).area

    def coords(self, n_quarter: int) -> np.ndarray:
        return np.asarray(self.vertices, dtype=float)

    def span(self, nx: float, ny: float, turn: float) -> tuple[float, float]:
        proj = (np.asarray(self.vertices) @ rotation_matrix(turn).T) @ np.array([nx, ny])
        return proj.min(), proj.max()

    def spans(self, nx: np.ndarray, ny: np.ndarray,
              turn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = self.points
        phi = np.radians(turn)
        c, s = np.cos(phi), np.sin(phi)
        px = c[..., None] * pts[:, 0] - s[..., None] * pts[:, 1]
        py = s[..., None] * pts[:, 0] + c[..., None] * pts[:, 1]
        proj = px * nx[..., None] + py * ny[..., None]
        return proj.min(axis=-1), proj.max(axis=-1)

    def support(self, ux: np.ndarray, uy: np.ndarray) -> np.ndarray:
        v = self.points
        return np.max(ux[..., None] * v[:, 0] + uy[..., None] * v[:, 1], axis=-1)

    def convex_pieces(self) -> tuple[Footprint, ...]:
        return tuple(PolygonOrifice(vertices=tuple(map(tuple, p.exterior.coords[:-1])))
                     for p in convex_decomposition(self.polygon()))

    def turned(self, angle: float) -> Footprint:
        if not angle:
            return self
        poly = shapely.affinity.rotate(self.polygon(), angle, origin=(0.0, 0.0))
        return PolygonOrifice(vertices=tuple(map(tuple, poly.exterior.coords[:-1])))

    @classmethod
    def from_spec(cls, spec, num, params, *, base_dir):
        if ("file" in params) == ("pts" in params):
            raise InputError(f"nozzle spec {excerpt(spec)}: a polygon needs a FILE or "
                             "pts=x y;x y;...")
        if "file" in params:
            path = Path(params["file"]).expanduser()
            if not path.is_absolute() and base_dir is not None:
                path = base_dir / path
            poly = _read_polygon_file(path)
        else:
            poly = _inline_polygon(spec, params["pts"])
        origin = params.get("origin", "file").lower()
        if origin not in ("file", "centroid"):
            raise InputError(f"nozzle spec {excerpt(spec)}: origin= expects 'file' or "
                             f"'centroid'; found {excerpt(origin)}")
        if origin == "centroid":
            c = poly.centroid
            poly = shapely.affinity.translate(poly, -c.x, -c.y)
        if "scale" in num:
            positive(spec, "scale", num["scale"])
            poly = shapely.affinity.scale(poly, num["scale"], num["scale"], origin=(0, 0))
        poly = shapely.affinity.rotate(poly, num.get("rot", 0.0), origin=(0, 0))
        poly = shapely.affinity.translate(poly, *_center(num))
        if poly.interiors:
            poly = Polygon(poly.exterior)  # an orifice with a hole is treated as its outline
        if poly.area <= 0:
            raise InputError(f"nozzle spec {excerpt(spec)}: the polygon has zero area")
        reach = max(map(abs, poly.bounds))
        if not reach <= NOZZLE_SIZE_RANGE[1]:
            raise InputError(f"nozzle spec {excerpt(spec)}: the polygon reaches {reach:g} mm "
                             f"from the rotation axis; expected within "
                             f"±{NOZZLE_SIZE_RANGE[1]:g} mm (scale= converts other units)")
        shell = shapely.geometry.polygon.orient(poly, 1.0).exterior.coords[:-1]
        return cls(vertices=tuple(map(tuple, shell)))


#: The shapes by SPEC name (each type's :attr:`Footprint.kind`).
SHAPES: dict[str, type[Footprint]] = {t.kind: t for t in (Circle, Ellipse, Rect, PolygonOrifice)}


# --------------------------------------------------------------------------- SPEC numbers

def number(spec: str, key: str, text: str) -> float:
    """The number of parameter ``key`` (finite; angles within ±3600°, offsets in range)."""
    if not _NUMBER.match(text.strip()):
        raise InputError(f"nozzle spec {excerpt(spec)}: {key}= expects a number; "
                         f"found {excerpt(text)}")
    value = float(text)
    if not math.isfinite(value):
        raise InputError(f"nozzle spec {excerpt(spec)}: {key}= must be finite; "
                         f"found {excerpt(text)}")
    if key in ("angle", "rot") and abs(value) > 3600:
        raise InputError(f"nozzle spec {excerpt(spec)}: {key}= expects an angle within ±3600 "
                         f"degrees; found {excerpt(text)}")
    if key in ("x", "y") and abs(value) > NOZZLE_SIZE_RANGE[1]:
        raise InputError(f"nozzle spec {excerpt(spec)}: {key}= expects an offset within "
                         f"±{NOZZLE_SIZE_RANGE[1]:g} mm; found {excerpt(text)}")
    return value


def positive(spec: str, key: str, value: float) -> float:
    """``value`` when it is a length within :data:`NOZZLE_SIZE_RANGE` (any positive scale)."""
    lo, hi = NOZZLE_SIZE_RANGE
    if value <= 0:
        raise InputError(
            f"nozzle spec {excerpt(spec)}: {key} must be a positive length in mm; found {value:g}"
        )
    if not (lo <= value <= hi) and key != "scale":
        raise InputError(f"nozzle spec {excerpt(spec)}: {key} must be between {lo:g} and "
                         f"{hi:g} mm; found {value:g}")
    return value


def _center(num: Mapping[str, float]) -> tuple[float, float]:
    return (num.get("x", 0.0), num.get("y", 0.0))


# --------------------------------------------------------------------------- polygon input

#: Largest nozzle outline file read (.wkt, .txt): an orifice has tens of vertices, not millions.
MAX_POLYGON_FILE = 16 << 20


def _inline_polygon(spec: str, text: str) -> Polygon:
    """The largest polygon of ``pts=x y;x y;...``."""
    pts = []
    for vertex in text.split(";"):
        fields = vertex.split()
        if len(fields) != 2:
            raise InputError(f"nozzle spec {excerpt(spec)}: pts= expects 'x y' pairs "
                             f"separated by ';'; found {excerpt(vertex)}")
        pts.append((number(spec, "pts", fields[0]), number(spec, "pts", fields[1])))
        if not all(abs(v) <= MAX_COORDINATE for v in pts[-1]):
            raise InputError(f"nozzle spec {excerpt(spec)}: pts= expects finite numbers up "
                             f"to {MAX_COORDINATE:g}; found {excerpt(vertex)}")
    if len(pts) < 3:
        raise InputError(f"nozzle spec {excerpt(spec)}: a polygon needs at least 3 vertices")
    polys = polygons_of(shapely.make_valid(Polygon(pts)))
    if not polys:
        raise InputError(f"nozzle spec {excerpt(spec)}: the polygon has no area")
    return max(polys, key=lambda p: p.area)


def _read_polygon_file(path: Path) -> Polygon:
    """Read a polygon outline: .wkt, .txt/.csv/.xy ("x y" per line), or .svg."""
    if not path.exists():
        raise PrintabilityOSError(f"{path}: nozzle polygon file not found")
    if not path.is_file():
        raise PrintabilityOSError(f"{path}: not a regular file (expected a nozzle outline: "
                                  ".svg, .wkt or 'x y' lines)")
    suffix = path.suffix.lower()
    if suffix != ".svg" and path.stat().st_size > MAX_POLYGON_FILE:
        raise FileFormatError(path, f"{path.stat().st_size / 2**20:.0f} MiB; a nozzle outline "
                              f"file is expected to be at most {MAX_POLYGON_FILE >> 20} MiB")
    if suffix == ".svg":
        # The SVG reader lives with the other layer sources.
        from printability.sources.svg import load_svg_region

        geom = load_svg_region(path)
    else:
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise PrintabilityOSError(f"{path}: cannot read nozzle polygon file ({exc})") from None
        if suffix == ".wkt":
            try:
                with warnings.catch_warnings():  # GEOS warns of "nan": checked below
                    warnings.simplefilter("ignore", RuntimeWarning)
                    geom = shapely.from_wkt(text.strip())
            except shapely.errors.GEOSException as exc:
                raise FileFormatError(
                    path, f"expected a WKT polygon ({excerpt(str(exc), 120)})") from None
            check_coordinates(path, shapely.get_coordinates(geom))
        else:
            pts = []
            for no, line in enumerate(text.splitlines(), 1):
                line = line.split("#", 1)[0].strip()
                if not line:
                    continue
                fields = line.replace(",", " ").split()
                if len(fields) != 2 or not all(_NUMBER.match(f) for f in fields):
                    raise FileFormatError(
                        path, f"expected two numbers 'x y'; found {excerpt(line)}", line=no)
                x, y = float(fields[0]), float(fields[1])
                if not (abs(x) <= MAX_COORDINATE and abs(y) <= MAX_COORDINATE):
                    raise FileFormatError(
                        path, f"expected finite numbers up to {MAX_COORDINATE:g}; found "
                        f"{excerpt(line)}", line=no)
                pts.append((x, y))
            if len(pts) < 3:
                raise FileFormatError(path, f"expected at least 3 vertices; found {len(pts)}")
            geom = Polygon(pts)
    polys = polygons_of(shapely.make_valid(geom))
    if not polys:
        raise FileFormatError(path, "no closed shape with positive area")
    if len(polys) > 1:
        polys.sort(key=lambda p: -p.area)
    return polys[0]

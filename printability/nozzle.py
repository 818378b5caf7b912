"""Nozzle footprints and the nozzle SPEC syntax.

A :class:`Nozzle` is one or several orifices (:class:`Footprint`) fixed on one
carriage, given in the nozzle frame (origin = the point the machine positions
and the axis the rotary joint turns about; see :mod:`printability.geometry`).

SPEC syntax (docs/design.md §4), parsed by :func:`parse_nozzle` from the kinds in
:data:`printability.options.NOZZLE_KINDS`::

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
import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely
import shapely.affinity
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.base import BaseGeometry

from printability.errors import FileFormatError, InputError, PrintabilityOSError, excerpt
from printability.geometry import polygons_of, rotation_matrix
from printability.options import NOZZLE_KINDS

__all__ = ["Footprint", "Nozzle", "parse_nozzle"]

_OUTLINE_MODES = ("inner", "outer")


@dataclass(frozen=True)
class Footprint:
    """One orifice in the nozzle frame.

    Attributes
    ----------
    kind
        One of :data:`printability.options.NOZZLE_KINDS`.
    a, b
        Semi-axes (mm): circle a = b = r; ellipse a = semi-major along the
        orifice's x axis, b = semi-minor; rectangle a = w/2, b = h/2.
        Unused (0) for polygons.
    center
        Position of the orifice centre in the nozzle frame, mm.
    rotation
        Orientation of the orifice in the nozzle frame, degrees.
    vertices
        Polygon shell vertices in the nozzle frame (polygons only; centre and
        rotation already applied), as a tuple of (x, y).
    """

    kind: str
    a: float = 0.0
    b: float = 0.0
    center: tuple[float, float] = (0.0, 0.0)
    rotation: float = 0.0
    vertices: tuple[tuple[float, float], ...] = ()

    @property
    def area(self) -> float:
        """Exact area, mm²."""
        if self.kind in ("circle", "ellipse"):
            return math.pi * self.a * self.b
        if self.kind == "rect":
            return 4.0 * self.a * self.b
        return Polygon(self.vertices).area

    @property
    def radius(self) -> float:
        """Largest distance from the nozzle origin to a point of the orifice, mm."""
        cx, cy = self.center
        if self.kind in ("circle", "ellipse"):
            return math.hypot(cx, cy) + self.a
        return float(np.max(np.hypot(*self._polygon_coords(0).T)))

    def _polygon_coords(self, n_quarter: int) -> np.ndarray:
        """Vertices (k, 2) in the nozzle frame; ellipses inscribed with 4·n_quarter points."""
        if self.kind == "polygon":
            return np.asarray(self.vertices, dtype=float)
        if self.kind == "rect":
            local = np.array([[self.a, self.b], [-self.a, self.b],
                              [-self.a, -self.b], [self.a, -self.b]])
        else:
            n = max(4 * n_quarter, 8)
            t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
            local = np.column_stack([self.a * np.cos(t), self.b * np.sin(t)])
        return local @ rotation_matrix(self.rotation).T + np.asarray(self.center)

    def polygon(self, *, quad_segs: int = 32, mode: str = "inner") -> Polygon:
        """Polygonal approximation in the nozzle frame.

        ``mode="inner"``: vertices on the curve (contained in the true
        orifice); ``mode="outer"``: the same polygon scaled about the centre
        by 1/cos(π/n) so it contains the true ellipse (n vertices). Both are
        exact for rectangles and polygons. The Hausdorff error of either is at
        most a·(1/cos(π/n) − 1) ≈ a·π²/(2n²).
        """
        if mode not in _OUTLINE_MODES:
            raise InputError(f"unknown outline mode {mode!r}; expected one of: inner, outer")
        coords = self._polygon_coords(quad_segs)
        if mode == "outer" and self.kind in ("circle", "ellipse"):
            n = len(coords)
            c = np.asarray(self.center)
            coords = c + (coords - c) / math.cos(math.pi / n)
        return Polygon(coords)


@dataclass(frozen=True)
class Nozzle:
    """A nozzle: one or more orifices that move together, plus a mounting angle.

    ``outline(angle)`` is R(mount_angle + angle)·A⁰ in the machine frame at the
    origin (see :mod:`printability.geometry` for the conventions).
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
        return len(self.footprints) == 1 and f.kind == "circle" and f.center == (0.0, 0.0)

    @property
    def symmetry_period(self) -> float:
        """Smallest angle (degrees) after which the outline repeats; 0 for a round nozzle.

        360 means no symmetry is exploited (offset or multi-orifice nozzles, polygons).
        """
        if self.is_round:
            return 0.0
        if len(self.footprints) == 1 and self.footprints[0].center == (0.0, 0.0):
            f = self.footprints[0]
            if f.kind == "rect" and math.isclose(f.a, f.b):
                return 90.0
            if f.kind in ("ellipse", "rect", "circle"):
                return 180.0
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
            phi = math.radians(self.mount_angle + angle + f.rotation)
            c, s = math.cos(phi), math.sin(phi)
            cx = c * f.center[0] - s * f.center[1]
            cy = s * f.center[0] + c * f.center[1]
            mid = cx * nx + cy * ny
            # the normal expressed in the orifice's own frame
            ux, uy = c * nx + s * ny, -s * nx + c * ny
            if f.kind in ("circle", "ellipse"):
                half = math.hypot(f.a * ux, f.b * uy)
            elif f.kind == "rect":
                half = abs(f.a * ux) + abs(f.b * uy)
            else:
                pts = np.asarray(f.vertices) @ rotation_matrix(self.mount_angle + angle).T
                proj = pts @ np.array([nx, ny])
                lo, hi = min(lo, proj.min()), max(hi, proj.max())
                continue
            lo, hi = min(lo, mid - half), max(hi, mid + half)
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
            if f.kind in ("circle", "ellipse", "rect"):
                phi = np.radians(self.mount_angle + ang + f.rotation)
                c, s = np.cos(phi), np.sin(phi)
                mid = (c * f.center[0] - s * f.center[1]) * nx \
                    + (s * f.center[0] + c * f.center[1]) * ny
                ux, uy = c * nx + s * ny, -s * nx + c * ny
                if f.kind == "rect":
                    half = np.abs(f.a * ux) + np.abs(f.b * uy)
                else:
                    half = np.hypot(f.a * ux, f.b * uy)
                lo = np.minimum(lo, mid - half)
                hi = np.maximum(hi, mid + half)
                continue
            # polygon: project the turned vertices on the normal
            pts = np.asarray(f.vertices, dtype=float)
            phi = np.radians(self.mount_angle + ang)
            c, s = np.cos(phi), np.sin(phi)
            px = c[..., None] * pts[:, 0] - s[..., None] * pts[:, 1]
            py = s[..., None] * pts[:, 0] + c[..., None] * pts[:, 1]
            proj = px * nx[..., None] + py * ny[..., None]
            lo = np.minimum(lo, proj.min(axis=-1))
            hi = np.maximum(hi, proj.max(axis=-1))
        return hi - lo


# --------------------------------------------------------------------------- parsing

_NUMBER = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$")
_COMMON = {"x", "y", "rot", "angle"}
_ALLOWED = {
    "circle": {"d", "r"} | _COMMON,
    "ellipse": {"major", "minor"} | _COMMON,
    "rect": {"w", "h"} | _COMMON,
    "polygon": {"file", "pts", "scale", "origin"} | _COMMON,
}


def _number(spec: str, key: str, text: str) -> float:
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


#: Orifice sizes a nozzle may have, mm: a micrometre to a metre (below, the analysis's
#: grids and footprints overflow; above, no printer).
NOZZLE_SIZE_RANGE = (1e-3, 1e3)


def _positive(spec: str, key: str, value: float) -> float:
    lo, hi = NOZZLE_SIZE_RANGE
    if value <= 0:
        raise InputError(
            f"nozzle spec {excerpt(spec)}: {key} must be a positive length in mm; found {value:g}"
        )
    if not (lo <= value <= hi) and key != "scale":
        raise InputError(f"nozzle spec {excerpt(spec)}: {key} must be between {lo:g} and "
                         f"{hi:g} mm; found {value:g}")
    return value


#: Largest nozzle outline file read (.wkt, .txt): an orifice has tens of vertices, not millions.
MAX_POLYGON_FILE = 16 << 20


def _read_polygon_file(path: Path) -> Polygon:
    """Read a polygon outline: .wkt, .txt/.csv/.xy ("x y" per line), or .svg."""
    from printability.sources._common import MAX_COORDINATE, check_coordinates

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


def _parse_part(part: str, spec: str, base_dir: Path | None) -> tuple[Footprint, float | None]:
    kind, _, rest = part.partition(":")
    kind = NOZZLE_KINDS.check(kind)
    params: dict[str, str] = {}
    if kind == "polygon" and rest and "=" not in rest.split(",", 1)[0]:
        first, _, rest = rest.partition(",")
        params["file"] = first
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, value = item.partition("=")
        key = key.strip().lower()
        if not eq:
            raise InputError(f"nozzle spec {excerpt(spec)}: expected key=value; "
                             f"found {excerpt(item)}")
        if key not in _ALLOWED[kind]:
            raise InputError(
                f"nozzle spec {excerpt(spec)}: unknown parameter {excerpt(key)} for a {kind}; "
                f"expected one of: {', '.join(sorted(_ALLOWED[kind]))}"
            )
        if key in params:
            raise InputError(f"nozzle spec {excerpt(spec)}: parameter {excerpt(key)} given twice")
        params[key] = value.strip()

    num = {k: _number(spec, k, v) for k, v in params.items()
           if k not in ("file", "pts", "origin")}
    center = (num.get("x", 0.0), num.get("y", 0.0))
    rot = num.get("rot", 0.0)
    angle = num.get("angle")

    if kind == "circle":
        if ("d" in num) == ("r" in num):
            raise InputError(f"nozzle spec {excerpt(spec)}: a circle needs exactly one of d= or r=")
        r = num["d"] / 2 if "d" in num else num["r"]
        _positive(spec, "the diameter", 2 * r)
        return Footprint("circle", r, r, center, 0.0), angle
    if kind == "ellipse":
        for k in ("major", "minor"):
            if k not in num:
                raise InputError(f"nozzle spec {excerpt(spec)}: an ellipse needs {k}= "
                                 "(full axis, mm)")
            _positive(spec, k, num[k])
        if num["minor"] > num["major"]:
            raise InputError(
                f"nozzle spec {excerpt(spec)}: minor ({num['minor']:g}) is larger than major "
                f"({num['major']:g}); swap them or use rot=90"
            )
        return Footprint("ellipse", num["major"] / 2, num["minor"] / 2, center, rot), angle
    if kind == "rect":
        for k in ("w", "h"):
            if k not in num:
                raise InputError(f"nozzle spec {excerpt(spec)}: a rectangle needs {k}= (mm)")
            _positive(spec, k, num[k])
        return Footprint("rect", num["w"] / 2, num["h"] / 2, center, rot), angle

    # polygon
    if ("file" in params) == ("pts" in params):
        raise InputError(f"nozzle spec {excerpt(spec)}: a polygon needs a FILE or pts=x y;x y;...")
    if "file" in params:
        path = Path(params["file"]).expanduser()
        if not path.is_absolute() and base_dir is not None:
            path = base_dir / path
        poly = _read_polygon_file(path)
    else:
        from printability.sources._common import MAX_COORDINATE

        pts = []
        for vertex in params["pts"].split(";"):
            fields = vertex.split()
            if len(fields) != 2:
                raise InputError(f"nozzle spec {excerpt(spec)}: pts= expects 'x y' pairs "
                                 f"separated by ';'; found {excerpt(vertex)}")
            pts.append((_number(spec, "pts", fields[0]), _number(spec, "pts", fields[1])))
            if not all(abs(v) <= MAX_COORDINATE for v in pts[-1]):
                raise InputError(f"nozzle spec {excerpt(spec)}: pts= expects finite numbers up "
                                 f"to {MAX_COORDINATE:g}; found {excerpt(vertex)}")
        if len(pts) < 3:
            raise InputError(f"nozzle spec {excerpt(spec)}: a polygon needs at least 3 vertices")
        polys = polygons_of(shapely.make_valid(Polygon(pts)))
        if not polys:
            raise InputError(f"nozzle spec {excerpt(spec)}: the polygon has no area")
        poly = max(polys, key=lambda p: p.area)
    origin = params.get("origin", "file").lower()
    if origin not in ("file", "centroid"):
        raise InputError(f"nozzle spec {excerpt(spec)}: origin= expects 'file' or 'centroid'; "
                         f"found {excerpt(origin)}")
    if origin == "centroid":
        c = poly.centroid
        poly = shapely.affinity.translate(poly, -c.x, -c.y)
    if "scale" in num:
        _positive(spec, "scale", num["scale"])
        poly = shapely.affinity.scale(poly, num["scale"], num["scale"], origin=(0, 0))
    poly = shapely.affinity.rotate(poly, rot, origin=(0, 0))
    poly = shapely.affinity.translate(poly, *center)
    if poly.interiors:
        poly = Polygon(poly.exterior)  # an orifice with a hole is treated as its outline
    if poly.area <= 0:
        raise InputError(f"nozzle spec {excerpt(spec)}: the polygon has zero area")
    reach = max(map(abs, poly.bounds))
    if not reach <= NOZZLE_SIZE_RANGE[1]:
        raise InputError(f"nozzle spec {excerpt(spec)}: the polygon reaches {reach:g} mm from "
                         f"the rotation axis; expected within ±{NOZZLE_SIZE_RANGE[1]:g} mm "
                         "(scale= converts other units)")
    shell = shapely.geometry.polygon.orient(poly, 1.0).exterior.coords[:-1]
    return Footprint("polygon", 0.0, 0.0, (0.0, 0.0), 0.0, tuple(map(tuple, shell))), angle


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

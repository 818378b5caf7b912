"""Helpers shared by the layer sources: files, units, memory estimates, ring nesting.

Private to :mod:`printability.sources`; the readers re-export what users need.
"""

from __future__ import annotations

import importlib
import math
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import shapely
import shapely.affinity
from shapely.geometry import MultiPolygon, Polygon

from printability.errors import (
    FileFormatError,
    InputError,
    PrintabilityOSError,
    ResourceError,
    excerpt,
)
from printability.model.geometry import MAX_COORDINATE, as_region, check_coordinates, polygons_of
from printability.model.layers import Layer, LayerStack
from printability.options import UNITS

__all__ = [
    "CLI_OPTIONS",
    "MAX_COORDINATE",
    "SVG_NUMBER",
    "UNIT_MM",
    "apply_fit",
    "check_coordinates",
    "check_memory",
    "check_positive",
    "fill_rings",
    "fill_segments",
    "lazy_import",
    "multipolygon",
    "nest_even_odd",
    "option_name",
    "planar_stack",
    "read_bytes",
    "require_file",
    "unit_scale",
    "winding_numbers",
    "xml_local_name",
]

#: Millimetres per unit, for every unit of :data:`printability.options.UNITS`.
UNIT_MM: dict[str, float] = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4, "px": 25.4 / 96.0}


#: A number as SVG writes it in path data and point lists.
SVG_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")


def xml_local_name(tag: Any) -> str:
    """An XML element's tag without its ``{namespace}`` (``""`` for comments and the like)."""
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def unit_scale(units: str | None, default: str = "mm") -> float:
    """Millimetres per unit of ``units`` (checked against the UNITS registry)."""
    return UNIT_MM[UNITS.check(default if units is None else units)]


#: The readers' keyword arguments that are options of the CLI, as the CLI spells them: a
#: message names the option the user typed (``--layer-height``, not ``layer_height``).
CLI_OPTIONS = {"layer_height": "--layer-height", "first_layer_height": "--first-layer-height",
               "units": "--units", "fit": "--fit", "map_scale": "--map-scale", "clip": "--clip",
               "keep_largest": "--keep-largest"}


def option_name(name: str) -> str:
    """A reader's keyword argument as the CLI option a user gives (``layer_height`` ->
    ``--layer-height``); a keyword with no CLI option as it is (``geographic=``)."""
    return CLI_OPTIONS.get(name, f"{name}=")


def check_positive(name: str, value: float | None) -> float | None:
    """``value`` as a float if it is a finite positive number (or None), else InputError
    naming the option (:func:`option_name`)."""
    if value is None:
        return None
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{option_name(name)} must be a positive number of mm; got "
                         f"{excerpt(str(value))}") from None
    if not (math.isfinite(v) and v > 0):
        raise InputError(f"{option_name(name)} must be a positive number of mm; got {v:g}")
    return v


def lazy_import(module: str, extra: str, purpose: str) -> Any:
    """Import an optional dependency or explain which extra installs it."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise InputError(
            f"reading {purpose} needs the optional package {module!r}; install it with "
            f"pip install 'printability[{extra}]'"
        ) from None


def require_file(path: str | Path) -> Path:
    """``path`` as a Path if it names a readable regular file, else PrintabilityOSError."""
    p = Path(path)
    if not p.exists():
        raise PrintabilityOSError(f"{p}: no such file")
    if not p.is_file():
        raise PrintabilityOSError(f"{p}: not a regular file")
    try:
        with p.open("rb"):
            pass
    except OSError as exc:
        raise PrintabilityOSError(f"{p}: cannot read ({exc.strerror or exc})") from None
    return p


def check_memory(path: Path, need: float, limit: int, what: str) -> None:
    """Refuse, before allocating, work whose estimated memory ``need`` exceeds ``limit``."""
    if need > limit:
        raise ResourceError(
            f"{path}: {what} would need about {need / 2**20:,.0f} MiB, more than the "
            f"{limit / 2**20:,.0f} MiB memory limit (Settings.max_memory); split or simplify "
            "the file, or raise the limit"
        )


def read_bytes(path: Path, *, factor: float, limit: int, what: str) -> bytes:
    """Read a whole file after checking that ``factor`` × its size fits in ``limit``.

    ``factor`` is the parser's peak memory per byte of input (Python objects for
    JSON and XML cost tens of bytes per input byte).
    """
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise PrintabilityOSError(f"{path}: cannot read ({exc.strerror or exc})") from None
    check_memory(path, size * factor, limit, what)
    try:
        return path.read_bytes()
    except OSError as exc:
        raise PrintabilityOSError(f"{path}: cannot read ({exc.strerror or exc})") from None


def apply_fit(geom: Any, fit: float | None) -> tuple[Any, float]:
    """Scale ``geom`` about the origin (0, 0) so its bounding box's longest side is ``fit`` mm.

    Returns the geometry and the factor applied (1 when ``fit`` is None).
    Scaling about the origin keeps a centred shape centred and a page's corner
    in place.
    """
    if fit is None:
        return geom, 1.0
    if not (0 < fit <= MAX_COORDINATE):
        raise InputError(f"--fit expects a size in mm above 0 and at most {MAX_COORDINATE:g}; "
                         f"found {fit:g}")
    minx, miny, maxx, maxy = geom.bounds
    longest = max(maxx - minx, maxy - miny)
    if not longest > 0:
        raise InputError(f"cannot fit a shape of zero extent to {fit} mm")
    k = fit / longest
    return shapely.affinity.scale(geom, k, k, origin=(0.0, 0.0)), k


def _ring_array(ring: Any) -> np.ndarray | None:
    a = np.asarray(ring, dtype=float)
    if a.ndim != 2 or a.shape[0] < 3 or a.shape[1] < 2:
        return None
    a = a[:, :2]
    if np.array_equal(a[0], a[-1]):
        a = a[:-1]
    return a if len(a) >= 3 else None


def nest_even_odd(rings: Iterable[Any], *, min_area: float = 0.0) -> list[Polygon]:
    """Polygons with holes from unmarked closed rings, by even-odd containment.

    A ring inside an even number of other rings is an outer boundary; inside an
    odd number, a hole of the smallest ring containing it. Rings must not cross
    (true of slicer outlines); a self-intersecting ring is first split by
    :func:`shapely.make_valid` into simple pieces. Orientation is ignored.
    """
    polys: list[Polygon] = []
    for r in rings:
        a = _ring_array(r)
        if a is None:
            continue
        p = Polygon(a)
        if not p.is_valid:
            pieces = polygons_of(shapely.make_valid(p))
            polys.extend(Polygon(q.exterior) for q in pieces)
        else:
            polys.append(p)
    polys = [p for p in polys if p.area > min_area]
    if not polys:
        return []
    areas = np.array([p.area for p in polys])
    order = np.argsort(-areas, kind="stable")
    polys = [polys[i] for i in order]
    areas = areas[order]
    # A point strictly inside each ring; ring j contains ring i iff j (larger) contains it.
    pts = shapely.point_on_surface(np.array(polys, dtype=object))
    tree = shapely.STRtree(polys)
    pi, pj = tree.query(pts, predicate="within")
    keep = pj < pi  # j earlier in the order = larger area (ties: earlier index)
    pi, pj = pi[keep], pj[keep]
    depth = np.bincount(pi, minlength=len(polys))
    parent = np.full(len(polys), -1)
    # Smallest containing ring = the one latest in the (descending-area) order.
    for i, j in zip(pi.tolist(), pj.tolist(), strict=True):
        if j > parent[i]:
            parent[i] = j
    holes: dict[int, list[Any]] = {}
    for i in range(len(polys)):
        if depth[i] % 2 == 1 and parent[i] >= 0:
            holes.setdefault(int(parent[i]), []).append(polys[i].exterior)
    out = []
    for i in range(len(polys)):
        if depth[i] % 2 == 0:
            out.append(Polygon(polys[i].exterior, holes.get(i, [])))
    return out


def winding_numbers(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Winding number of each point about the directed edges a[k] → b[k] (closed curves)."""
    wn = np.zeros(len(points), dtype=np.int64)
    # Bound the m × n temporaries to a few million entries.
    step = max(1, 4_000_000 // max(1, len(a)))
    for s in range(0, len(points), step):
        px = points[s : s + step, 0:1]
        py = points[s : s + step, 1:2]
        cross = (b[:, 0] - a[:, 0]) * (py - a[:, 1]) - (px - a[:, 0]) * (b[:, 1] - a[:, 1])
        up = (a[:, 1] <= py) & (b[:, 1] > py) & (cross > 0)
        down = (a[:, 1] > py) & (b[:, 1] <= py) & (cross < 0)
        wn[s : s + step] = up.sum(axis=1) - down.sum(axis=1)
    return wn


def fill_segments(a: np.ndarray, b: np.ndarray, rule: str) -> Any:
    """The filled region of closed curves given as directed segments a[k] → b[k].

    The segments are noded into an arrangement; a face is kept when the winding
    number of an interior point is non-zero (``rule="nonzero"``) or odd
    (``"evenodd"``). Exact for crossing curves; needs no ring assembly.
    """
    if not len(a):
        return Polygon()
    segs = shapely.linestrings(np.stack([a, b], axis=1))
    faces = np.asarray(shapely.get_parts(shapely.polygonize(shapely.get_parts(
        shapely.node(shapely.multilinestrings(segs))))))
    if not len(faces):
        return Polygon()
    faces = faces[shapely.area(faces) > 0]
    if not len(faces):
        return Polygon()
    pts = shapely.get_coordinates(shapely.point_on_surface(faces))
    wn = winding_numbers(pts, a, b)
    kept = faces[(wn != 0) if rule == "nonzero" else (wn % 2 == 1)]
    if not len(kept):
        return Polygon()
    try:
        return shapely.coverage_union_all(kept)
    except shapely.errors.GEOSException:  # faces from polygonize form a coverage; be safe
        return shapely.union_all(kept)


def fill_rings(rings: Iterable[Any], rule: str) -> Any:
    """The region SVG-style filling paints for closed ``rings`` under ``rule``.

    ``rule`` is ``"nonzero"`` or ``"evenodd"`` (SVG's fill-rule); see
    :func:`fill_segments`. Orientation matters for nonzero, as in SVG.
    """
    arrs = [r for r in (_ring_array(r) for r in rings) if r is not None]
    if not arrs:
        return Polygon()
    a = np.concatenate(arrs)
    b = np.concatenate([np.roll(r, -1, axis=0) for r in arrs])
    return fill_segments(a, b, rule)


def planar_stack(
    geom: Any,
    *,
    path: Path,
    meta: dict[str, Any],
    min_area: float = 0.0,
) -> LayerStack:
    """One planar layer (z = 0, height 0) holding ``geom``; FileFormatError if it has no area."""
    if geom is None or geom.is_empty or not polygons_of(geom):
        raise FileFormatError(
            path, "no closed shape with positive area; expected at least one closed outline"
        )
    try:
        region = as_region(geom, name=str(path), min_area=min_area)
    except InputError as exc:
        raise FileFormatError(path, str(exc).removeprefix(f"{path}: ")) from None
    meta.setdefault("warnings", [])
    return LayerStack(
        (Layer(z=0.0, height=0.0, region=region, index=0),), source=str(path), meta=meta
    )


def multipolygon(polys: Sequence[Polygon]) -> MultiPolygon:
    """A MultiPolygon of ``polys`` (for building layers that as_region validates)."""
    return MultiPolygon(list(polys))

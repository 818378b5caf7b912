"""GeoJSON and WKT outlines.

GeoJSON
    A ``Feature``, a ``FeatureCollection``, a ``GeometryCollection`` or a bare
    geometry; only ``Polygon`` and ``MultiPolygon`` carry area (points and lines
    are counted in ``meta["skipped"]``). Rings may be oriented either way: the
    shared Natural Earth files have clockwise exteriors, RFC 7946 asks for
    counter-clockwise ones, so orientation is ignored (the first ring of a
    polygon is its exterior, the others its holes).

Geographic coordinates
    RFC 7946 GeoJSON is longitude/latitude in degrees (WGS84), and so is any
    file whose coordinates all lie within ±180° × ±90° unless ``geographic=False``
    says otherwise. Such data are projected with a **local equirectangular
    projection about the centre of the kept data's bounding box**
    (lon0, lat0)::

        x = (lon − lon0) · 111.32 km · cos(lat0)
        y = (lat − lat0) · 110.57 km

    It keeps areas within about 1 % over a few degrees of latitude, which is
    plenty for a printable sketch, but it is not a map projection for large
    regions (Norway with Svalbard and Bouvet Island spans 135° of latitude: clip
    first). Data crossing the antimeridian are not handled. Projected kilometres
    then need a print scale: ``fit=MM`` scales the longest side to MM mm, or
    ``map_scale=`` gives mm on the print per km on the ground. One of the two
    is required.

Selecting parts
    ``clip=(xmin, ymin, xmax, ymax)`` keeps only what lies inside a box given in
    the file's coordinates (lon/lat for geographic data), applied before the
    projection; ``keep_largest=N`` then keeps the N polygons of largest area.
    Japan's main islands: ``clip=(128, 30, 146, 46)`` or ``keep_largest=4``.

WKT
    A ``.wkt`` file holds one WKT geometry (or several, one per line); its
    coordinates are plane coordinates in ``units`` (mm by default).
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import shapely
import shapely.affinity
from shapely.geometry import MultiPolygon, Polygon, box

from printability.errors import FileFormatError, InputError, excerpt
from printability.model.geometry import polygons_of
from printability.model.layers import LayerStack
from printability.settings import DEFAULT_SETTINGS, Settings
from printability.sources._common import (
    MAX_COORDINATE,
    apply_fit,
    check_coordinates,
    check_positive,
    planar_stack,
    read_bytes,
    require_file,
    unit_scale,
)

__all__ = [
    "KM_PER_DEG_LAT",
    "KM_PER_DEG_LON_EQUATOR",
    "load_geojson_layers",
    "load_wkt_layers",
    "project_equirectangular",
]

KM_PER_DEG_LON_EQUATOR = 111.32
"""Kilometres per degree of longitude at the equator (WGS84, rounded)."""
KM_PER_DEG_LAT = 110.57
"""Kilometres per degree of latitude (WGS84 mean near the equator, rounded)."""

# Peak memory of a load per byte of the file, measured on files of many small polygons (the
# worst case: a shapely object, a GEOS geometry and their union's share per polygon): 39 for
# GeoJSON (json.loads builds Python floats and lists), 45-49 for WKT; 11 for one polygon of
# 850 000 vertices. The guard said 40, which a 20 MB WKT file passed to use 45.
_BYTES_PER_INPUT_BYTE = 60.0
_POLYGONAL = ("Polygon", "MultiPolygon")
_OTHER_GEOMS = ("Point", "MultiPoint", "LineString", "MultiLineString")


def project_equirectangular(geom: Any, lon0: float, lat0: float) -> Any:
    """Project lon/lat degrees to km, local equirectangular about (lon0, lat0)."""
    kx = KM_PER_DEG_LON_EQUATOR * math.cos(math.radians(lat0))
    ky = KM_PER_DEG_LAT
    return shapely.transform(geom, lambda c: (c - (lon0, lat0)) * (kx, ky))


def _rings_polygon(path: Path, coords: Any, where: str) -> Polygon:
    if not isinstance(coords, list) or not coords:
        raise FileFormatError(path, "expected a Polygon's coordinates as a non-empty list of "
                              f"rings; found {type(coords).__name__}", element=where)
    rings = []
    for k, ring in enumerate(coords):
        try:
            a = np.asarray(ring, dtype=float)
        except OverflowError:  # JSON integers have no limit: 400 digits are not a float
            raise FileFormatError(path, f"ring {k}: a coordinate is out of range (an integer "
                                  "beyond any float); expected finite numbers up to "
                                  f"{MAX_COORDINATE:g}", element=where) from None
        except (TypeError, ValueError):
            raise FileFormatError(path, f"ring {k}: expected a list of [x, y] positions",
                                  element=where) from None
        if a.ndim != 2 or a.shape[1] < 2:
            raise FileFormatError(path, f"ring {k}: expected a list of [x, y] positions; "
                                  f"found an array of shape {a.shape}", element=where)
        if len(a) < 4 and k == 0:
            raise FileFormatError(path, f"ring {k}: expected at least 4 positions (a closed "
                                  f"ring); found {len(a)}", element=where)
        if not np.isfinite(a).all():
            raise FileFormatError(path, f"ring {k}: non-finite coordinate", element=where)
        check_coordinates(path, a, element=f"{where} ring {k}")
        if len(a) >= 4:
            rings.append(a[:, :2])
    # Orientation is irrelevant to shapely's area and validity.
    return Polygon(rings[0], rings[1:])


def _collect(path: Path, obj: Any, where: str, out: list[Polygon], skipped: list[str]) -> None:
    if not isinstance(obj, dict):
        raise FileFormatError(path, f"expected a GeoJSON object; found {type(obj).__name__}",
                              element=where)
    kind = obj.get("type")
    if kind == "FeatureCollection":
        feats = obj.get("features")
        if not isinstance(feats, list):
            raise FileFormatError(path, "expected 'features' to be a list", element=where)
        for i, f in enumerate(feats):
            _collect(path, f, f"{where}.features[{i}]", out, skipped)
    elif kind == "Feature":
        g = obj.get("geometry")
        if g is None:
            skipped.append(f"{where} (no geometry)")
        else:
            _collect(path, g, f"{where}.geometry", out, skipped)
    elif kind == "GeometryCollection":
        geoms = obj.get("geometries")
        if not isinstance(geoms, list):
            raise FileFormatError(path, "expected 'geometries' to be a list", element=where)
        for i, g in enumerate(geoms):
            _collect(path, g, f"{where}.geometries[{i}]", out, skipped)
    elif kind == "Polygon":
        out.append(_rings_polygon(path, obj.get("coordinates"), where))
    elif kind == "MultiPolygon":
        coords = obj.get("coordinates")
        if not isinstance(coords, list):
            raise FileFormatError(path, "expected MultiPolygon coordinates to be a list",
                                  element=where)
        for i, c in enumerate(coords):
            out.append(_rings_polygon(path, c, f"{where}.coordinates[{i}]"))
    elif kind in _OTHER_GEOMS:
        skipped.append(f"{where} ({kind})")
    else:
        raise FileFormatError(
            path, "expected a GeoJSON type (FeatureCollection, Feature, GeometryCollection, "
            f"Polygon, MultiPolygon...); found type {excerpt(str(kind))}", element=where)


def _select(
    polys: list[Polygon],
    *,
    clip: Sequence[float] | None,
    keep_largest: int | None,
) -> list[Polygon]:
    if clip is not None:
        try:
            xmin, ymin, xmax, ymax = (float(v) for v in clip)
        except (TypeError, ValueError):
            raise InputError(f"clip must be (xmin, ymin, xmax, ymax); got {clip!r}") from None
        if not (xmin < xmax and ymin < ymax):
            raise InputError(f"clip box is empty: {clip!r}; expected xmin < xmax, ymin < ymax")
        b = box(xmin, ymin, xmax, ymax)
        clipped = []
        for p in polys:
            if p.within(b):
                clipped.append(p)
            elif p.intersects(b):
                clipped.extend(polygons_of(shapely.make_valid(p).intersection(b)))
        polys = clipped
    if keep_largest is not None:
        if not isinstance(keep_largest, int) or keep_largest < 1:
            raise InputError(f"keep_largest must be a positive integer; got {keep_largest!r}")
        polys = sorted(polys, key=lambda p: -p.area)[:keep_largest]
    return polys


def _finish(
    p: Path,
    polys: list[Polygon],
    *,
    geographic: bool,
    units: str | None,
    fit: float | None,
    map_scale: float | None,
    clip: Sequence[float] | None,
    keep_largest: int | None,
    meta: dict[str, Any],
    settings: Settings,
) -> LayerStack:
    fit = check_positive("fit", fit)
    map_scale = check_positive("map_scale", map_scale)
    n_read = len(polys)
    polys = [q for q in (shapely.make_valid(p) if not p.is_valid else p for p in polys)
             for q in polygons_of(q)]
    if geographic:
        # Choose among polygons by their projected (true) area, not by square degrees.
        polys = _select(polys, clip=clip, keep_largest=None)
        if not polys:
            raise FileFormatError(p, f"no polygon left inside the clip box {tuple(clip or ())}")
        if keep_largest is not None:
            _select([], clip=None, keep_largest=keep_largest)  # validates the value
            minx, miny, maxx, maxy = MultiPolygon(polys).bounds
            c = ((minx + maxx) / 2, (miny + maxy) / 2)
            true_area = [project_equirectangular(q, *c).area for q in polys]
            order = np.argsort(true_area, kind="stable")[::-1][:keep_largest]
            polys = [polys[i] for i in sorted(order)]
        # Project about the centre of what is kept, so the scale is right where it matters.
        minx, miny, maxx, maxy = MultiPolygon(polys).bounds
        lon0, lat0 = (minx + maxx) / 2, (miny + maxy) / 2
        geom = MultiPolygon([project_equirectangular(q, lon0, lat0) for q in polys])
        if fit is None and map_scale is None:
            raise InputError(
                f"{p}: the coordinates are read as longitude/latitude degrees (GeoJSON's "
                "rule, and all lie within ±180° × ±90°); after projection they are "
                "kilometres, so give a print scale: fit=MM (longest side in mm) or "
                "map_scale= (mm per km); if they are plane coordinates, pass geographic=False")
        if units is not None:
            raise InputError(f"{p}: units= does not apply to longitude/latitude data; use "
                             "fit= or map_scale=")
        meta["projection"] = {
            "kind": "local equirectangular",
            "lon0": lon0,
            "lat0": lat0,
            "km_per_deg_lon": KM_PER_DEG_LON_EQUATOR * math.cos(math.radians(lat0)),
            "km_per_deg_lat": KM_PER_DEG_LAT,
        }
        if map_scale is not None and fit is None:
            geom = shapely.affinity.scale(geom, map_scale, map_scale, origin=(0, 0))
            meta["scale"] = map_scale
            meta["scale_unit"] = "mm per km"
        else:
            if map_scale is not None:
                raise InputError("give fit= or map_scale=, not both")
            geom, f = apply_fit(geom, fit)
            meta["scale"] = f
            meta["scale_unit"] = "mm per km"
    else:
        if map_scale is not None:
            raise InputError(f"{p}: map_scale= applies to longitude/latitude data only; these "
                             "coordinates are planar (use units= or fit=)")
        k = unit_scale(units)
        polys = _select(polys, clip=clip, keep_largest=keep_largest)
        if not polys:
            raise FileFormatError(p, f"no polygon left inside the clip box {tuple(clip or ())}")
        geom = MultiPolygon(polys)
        if k != 1.0:
            geom = shapely.affinity.scale(geom, k, k, origin=(0, 0))
        geom, f = apply_fit(geom, fit)
        meta["scale"] = k * f
    meta["polygons_read"] = n_read
    meta["geographic"] = geographic
    return planar_stack(geom, path=p, meta=meta, min_area=0.0)


def _is_lonlat(polys: list[Polygon]) -> bool:
    if not polys:
        return False
    minx, miny, maxx, maxy = MultiPolygon(polys).bounds
    return -180.0 <= minx and maxx <= 180.0 and -90.0 <= miny and maxy <= 90.0


def load_geojson_layers(
    path: str | Path,
    *,
    fit: float | None = None,
    map_scale: float | None = None,
    units: str | None = None,
    geographic: bool | None = None,
    clip: Sequence[float] | None = None,
    keep_largest: int | None = None,
    settings: Settings = DEFAULT_SETTINGS,
) -> LayerStack:
    """Read the polygons of a GeoJSON file as one planar layer.

    Parameters
    ----------
    path
        ``.geojson`` / ``.json`` file.
    fit
        Scale the (projected) outline so its longest side is ``fit`` mm.
    map_scale
        For geographic data: mm on the print per km on the ground (instead of ``fit``).
    units
        For planar (non-geographic) data: the unit of the coordinates (default mm).
    geographic
        Force (True) or deny (False) the lon/lat interpretation; by default data
        are geographic when the file declares no projected ``crs`` and every
        coordinate lies within ±180 × ±90.
    clip
        ``(xmin, ymin, xmax, ymax)`` in the file's coordinates: keep what lies inside.
    keep_largest
        Keep only the N largest polygons (by true area).
    settings
        ``max_memory`` bounds the parse.

    Returns
    -------
    LayerStack
        One layer; ``meta`` holds ``projection`` (for geographic data), ``scale``,
        ``polygons_read``, ``skipped`` (non-polygonal members) and ``warnings``.

    Raises
    ------
    FileFormatError
        Not JSON, not GeoJSON, malformed coordinates (named by their JSON path),
        or no polygon.
    InputError
        Geographic data without ``fit`` or ``map_scale``.
    """
    p = require_file(path)
    raw = read_bytes(p, factor=_BYTES_PER_INPUT_BYTE, limit=settings.max_memory,
                     what="parsing this GeoJSON file")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise FileFormatError(p, "expected UTF-8 JSON text; found binary data at byte "
                              f"{exc.start}") from None
    try:
        obj = json.loads(text)
        polys: list[Polygon] = []
        skipped: list[str] = []
        _collect(p, obj, "$", polys, skipped)
    except json.JSONDecodeError as exc:
        raise FileFormatError(p, f"expected JSON; {exc.msg} (column {exc.colno})",
                              line=exc.lineno) from None
    except RecursionError:
        raise FileFormatError(p, "the JSON is nested too deeply to be GeoJSON") from None
    if not polys:
        raise FileFormatError(p, "no Polygon or MultiPolygon geometry; expected at least one "
                              f"polygon (found only: {', '.join(skipped) or 'nothing'})")
    crs = obj.get("crs") if isinstance(obj, dict) else None
    declared = json.dumps(crs) if crs is not None else ""
    if geographic is None:
        projected_crs = bool(crs) and not any(t in declared for t in ("4326", "CRS84", "crs84"))
        geographic = (not projected_crs) and _is_lonlat(polys)
    meta: dict[str, Any] = {"format": "geojson", "skipped": skipped, "warnings": []}
    if declared:
        meta["crs"] = crs
    return _finish(p, polys, geographic=geographic, units=units, fit=fit,
                   map_scale=map_scale, clip=clip, keep_largest=keep_largest, meta=meta,
                   settings=settings)


def load_wkt_layers(
    path: str | Path,
    *,
    units: str | None = None,
    fit: float | None = None,
    clip: Sequence[float] | None = None,
    keep_largest: int | None = None,
    settings: Settings = DEFAULT_SETTINGS,
) -> LayerStack:
    """Read the polygons of a WKT file (planar coordinates) as one planar layer.

    Parameters
    ----------
    path
        ``.wkt`` file: one WKT geometry, or one per line.
    units
        Unit of the coordinates (default mm).
    fit
        Scale so the longest side is ``fit`` mm.
    clip, keep_largest
        As for :func:`load_geojson_layers`.
    settings
        ``max_memory`` bounds the parse.
    """
    p = require_file(path)
    raw = read_bytes(p, factor=_BYTES_PER_INPUT_BYTE, limit=settings.max_memory,
                     what="parsing this WKT file")
    try:
        text = raw.decode("utf-8-sig").strip()
    except UnicodeDecodeError as exc:
        raise FileFormatError(p, "expected WKT text; found binary data at byte "
                              f"{exc.start}") from None
    if not text:
        raise FileFormatError(p, "the file is empty; expected a WKT geometry such as "
                              "POLYGON ((0 0, 10 0, 10 5, 0 0))")
    try:
        with warnings.catch_warnings():
            # GEOS reads "nan" and warns with its source path; the check below says it plainly
            warnings.simplefilter("ignore", RuntimeWarning)
            geoms = [shapely.from_wkt(text)]
    except shapely.errors.GEOSException:
        geoms = []
        for no, line in enumerate(text.splitlines(), 1):
            if not line.strip():
                continue
            try:
                geoms.append(shapely.from_wkt(line.strip()))
            except shapely.errors.GEOSException as exc:
                raise FileFormatError(p, f"expected a WKT geometry ({excerpt(str(exc), 120)})",
                                      line=no) from None
    for g in geoms:
        check_coordinates(p, shapely.get_coordinates(g))
    polys = [q for g in geoms for q in polygons_of(g)]
    if not polys:
        kinds = sorted({g.geom_type for g in geoms})
        raise FileFormatError(p, "no polygon; expected POLYGON or MULTIPOLYGON, found "
                              + ", ".join(kinds))
    meta: dict[str, Any] = {"format": "wkt", "warnings": []}
    return _finish(p, polys, geographic=False, units=units, fit=fit, map_scale=None,
                   clip=clip, keep_largest=keep_largest, meta=meta, settings=settings)

"""GeoJSON and WKT sources: the shared coastlines, projection, selection, malformed files."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import shapely
from shapely.geometry import MultiPolygon, Polygon, mapping

from printability.errors import FileFormatError, InputError, ResourceError
from printability.settings import Settings
from printability.sources.geo import (
    KM_PER_DEG_LAT,
    KM_PER_DEG_LON_EQUATOR,
    load_geojson_layers,
    load_wkt_layers,
    project_equirectangular,
)

# ../shared/data/SOURCES.md: polygon counts and lon/lat bounding boxes.
COAST = {
    "japan_10m.geojson": (109, (122.938, 24.212, 153.986, 45.520)),
    "japan_50m.geojson": (34, (123.680, 24.266, 145.833, 45.510)),
    "japan_110m.geojson": (3, (129.408, 31.030, 145.543, 45.551)),
    "norway_10m.geojson": (120, (-9.117, -54.462, 33.640, 80.770)),
    "united_kingdom_10m.geojson": (57, (-13.691, 49.910, 1.771, 60.848)),
    "greece_10m.geojson": (74, (19.626, 34.815, 28.240, 41.750)),
}


@pytest.mark.parametrize("name", sorted(COAST))
def test_coastlines_project_and_fit(shared_data: Path, name: str):
    count, (x0, y0, x1, y1) = COAST[name]
    stack = load_geojson_layers(shared_data / name, fit=200.0)
    assert stack.meta["polygons_read"] == count
    assert len(stack[0].region.geoms) == count  # no holes, no touching islands
    proj = stack.meta["projection"]
    assert proj["lon0"] == pytest.approx((x0 + x1) / 2, abs=1e-3)
    assert proj["lat0"] == pytest.approx((y0 + y1) / 2, abs=1e-3)
    minx, miny, maxx, maxy = stack[0].region.bounds
    assert max(maxx - minx, maxy - miny) == pytest.approx(200.0)
    # Width/height ratio of the projected box = Δlon·cos(lat0)·111.32 / (Δlat·110.57).
    ratio = ((x1 - x0) * KM_PER_DEG_LON_EQUATOR * math.cos(math.radians(proj["lat0"]))
             / ((y1 - y0) * KM_PER_DEG_LAT))
    assert (maxx - minx) / (maxy - miny) == pytest.approx(ratio, rel=1e-3)
    # The projection is centred: the box is symmetric about the origin.
    assert (minx + maxx, miny + maxy) == pytest.approx((0.0, 0.0), abs=1e-6)


def test_japan_main_islands(shared_data: Path):
    largest = load_geojson_layers(shared_data / "japan_10m.geojson", keep_largest=4,
                                  map_scale=1.0)  # 1 mm per km: areas in km²
    areas = sorted((g.area for g in largest[0].region.geoms), reverse=True)
    # Honshu ~229,000 km² (SOURCES.md). One equirectangular scale for 31–45.5° N overstates
    # the northern Hokkaido and understates Kyushu by several %: the documented price.
    assert areas[0] == pytest.approx(229_000, rel=0.03)
    assert areas[1] == pytest.approx(78_000, rel=0.10)
    assert areas[2] == pytest.approx(37_000, rel=0.10)
    assert areas[3] == pytest.approx(18_000, rel=0.10)
    clipped = load_geojson_layers(shared_data / "japan_10m.geojson", clip=(128, 30, 146, 46),
                                  map_scale=1.0)
    assert clipped.meta["polygons_read"] == 109
    # Yonaguni/Yaeyama, Senkaku, Iwo Jima, Minami-Torishima fall outside the box.
    n = len(clipped[0].region.geoms)
    assert 4 < n < 109
    assert clipped[0].area > sum(areas)
    lon0, lat0 = clipped.meta["projection"]["lon0"], clipped.meta["projection"]["lat0"]
    assert 128 <= lon0 <= 146 and 30 <= lat0 <= 46


def test_projection_of_a_one_degree_cell():
    cell = shapely.box(10.0, 44.5, 11.0, 45.5)
    area = project_equirectangular(cell, 10.5, 45.0).area
    assert area == pytest.approx(KM_PER_DEG_LON_EQUATOR * math.cos(math.radians(45.0))
                                 * KM_PER_DEG_LAT)


def _write(tmp_path: Path, obj, name: str = "g.geojson") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(obj))
    return path


def test_ring_orientation_does_not_matter(tmp_path: Path):
    ccw = Polygon([(0, 0), (10, 0), (10, 10), (0, 10)], [[(2, 2), (2, 4), (4, 4), (4, 2)]])
    cw = Polygon(ccw.exterior.coords[::-1], [ccw.interiors[0].coords[::-1]])
    for poly in (ccw, cw):
        stack = load_geojson_layers(_write(tmp_path, mapping(poly)), geographic=False)
        assert stack[0].area == pytest.approx(96.0)


def test_feature_collection_and_planar_units(tmp_path: Path):
    fc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": mapping(shapely.box(0, 0, 2, 1))},
        {"type": "Feature", "properties": {}, "geometry": {"type": "Point",
                                                           "coordinates": [0, 0]}},
        {"type": "Feature", "properties": {}, "geometry": None},
        {"type": "Feature", "properties": {}, "geometry": {
            "type": "GeometryCollection",
            "geometries": [mapping(MultiPolygon([shapely.box(5, 0, 6, 1)]))]}},
    ]}
    path = _write(tmp_path, fc)
    stack = load_geojson_layers(path, geographic=False, units="cm")
    assert stack[0].area == pytest.approx(300.0)
    assert len(stack.meta["skipped"]) == 2
    # Small lon/lat-looking coordinates are geographic unless said otherwise.
    with pytest.raises(InputError, match=r"fit=MM.*map_scale"):
        load_geojson_layers(path)


def test_projected_crs_is_not_geographic(tmp_path: Path):
    obj = {"type": "Feature", "crs": {"type": "name",
                                      "properties": {"name": "urn:ogc:def:crs:EPSG::3857"}},
           "geometry": mapping(shapely.box(0, 0, 50, 20)), "properties": {}}
    stack = load_geojson_layers(_write(tmp_path, obj))
    assert not stack.meta["geographic"] and stack[0].area == pytest.approx(1000.0)


@pytest.mark.parametrize(("text", "match"), [
    ('{"type": "Polygon", "coordinates": [[[0, 0], [1, 0]', r"line 1: expected JSON"),
    ('{"type": "Circle", "coordinates": []}', r"\$: expected a GeoJSON type.*'Circle'"),
    ('{"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [0, 0]]]}',
     r"\$: ring 0: expected at least 4 positions"),
    ('{"type": "Polygon", "coordinates": [[[0, "a"], [1, 0], [1, 1], [0, 0]]]}',
     r"\$: ring 0: expected a list of \[x, y\] positions"),
    ('{"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": '
     '{"type": "MultiPolygon", "coordinates": 5}}]}',
     r"\$\.features\[0\]\.geometry: expected MultiPolygon coordinates to be a list"),
    ('{"type": "LineString", "coordinates": [[0, 0], [1, 1]]}', "no Polygon or MultiPolygon"),
    ('{"type": "GeometryCollection", "geometries": [' * 5000 + "]}" * 5000,
     "nested too deeply"),
], ids=["truncated-json", "unknown-type", "short-ring", "non-number", "bad-multipolygon",
        "lines-only", "deep-nesting"])
def test_malformed_geojson(tmp_path: Path, text: str, match: str):
    path = tmp_path / "bad.geojson"
    path.write_text(text)
    with pytest.raises(FileFormatError, match=r"bad\.geojson.*" + match):
        load_geojson_layers(path, fit=10)


def test_geojson_memory_estimate(shared_data: Path):
    with pytest.raises(ResourceError, match=r"norway_10m\.geojson.*memory limit"):
        load_geojson_layers(shared_data / "norway_10m.geojson", fit=100,
                            settings=Settings(max_memory=1 << 20))


def test_options_are_checked(shared_data: Path):
    path = shared_data / "japan_110m.geojson"
    with pytest.raises(InputError, match="keep_largest"):
        load_geojson_layers(path, fit=10, keep_largest=0)
    with pytest.raises(InputError, match="clip box is empty"):
        load_geojson_layers(path, fit=10, clip=(146, 30, 128, 46))
    with pytest.raises(InputError, match="fit must be a positive"):
        load_geojson_layers(path, fit=-1)
    with pytest.raises(InputError, match="units= does not apply"):
        load_geojson_layers(path, fit=10, units="mm")


def test_wkt(tmp_path: Path):
    path = tmp_path / "shape.wkt"
    path.write_text("POLYGON ((0 0, 4 0, 4 3, 0 3, 0 0), (1 1, 2 1, 2 2, 1 2, 1 1))\n")
    assert load_wkt_layers(path)[0].area == pytest.approx(11.0)
    assert load_wkt_layers(path, units="in")[0].area == pytest.approx(11.0 * 25.4**2)
    two = tmp_path / "two.wkt"
    two.write_text("POLYGON ((0 0, 1 0, 1 1, 0 0))\nMULTIPOLYGON (((5 5, 7 5, 7 7, 5 5)))\n")
    stack = load_wkt_layers(two, keep_largest=1)
    assert stack[0].area == pytest.approx(2.0)
    bad = tmp_path / "bad.wkt"
    bad.write_text("POLYGON ((0 0, 1 0, 1 1, 0 0))\nPOLYGON ((0 0, 1 0\n")
    with pytest.raises(FileFormatError, match=r"bad\.wkt, line 2: expected a WKT geometry"):
        load_wkt_layers(bad)
    line = tmp_path / "line.wkt"
    line.write_text("LINESTRING (0 0, 1 1)")
    with pytest.raises(FileFormatError, match=r"no polygon.*LineString"):
        load_wkt_layers(line)

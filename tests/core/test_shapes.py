"""Orifice shapes as types (printability.model.shapes): each answers the engines' questions, checked
against the orifice's own outline (GEOS) as the oracle."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
import shapely.affinity
from shapely.geometry import Point

from printability.generate._group_kernel import _bead_width, measures, orifice_of
from printability.model.nozzle import parse_nozzle
from printability.model.shapes import BOX, CONIC, POLYGON, SHAPES, Footprint
from printability.options import NOZZLE_KINDS

# one of each shape, offset and turned in the nozzle frame, and heads of several orifices
SPECS = [
    "circle:d=0.4",
    "circle:d=0.4,x=0.3,y=-0.1",
    "ellipse:major=0.8,minor=0.3",
    "ellipse:major=0.8,minor=0.3,rot=25,x=0.2,y=0.1,angle=10",
    "rect:w=0.7,h=0.3",
    "rect:w=0.7,h=0.3,rot=-40,x=-0.2",
    "polygon:pts=0 0;0.6 0;0.6 0.2;0.2 0.2;0.2 0.5;0 0.5,origin=centroid",
    "polygon:pts=0 0;0.7 0;0.35 0.3,rot=15,x=0.1",
    "ellipse:major=0.5,minor=0.2,rot=30,x=0.6+rect:w=0.3,h=0.1,rot=-20,y=0.5",
    "circle:d=0.3,x=-0.5+polygon:pts=0 0;0.3 0;0 0.3,x=0.4",
]


def test_every_nozzle_kind_is_a_shape_type():
    assert set(SHAPES) == set(NOZZLE_KINDS.choices)
    for name, shape in SHAPES.items():
        assert issubclass(shape, Footprint) and shape.kind == name
        assert shape.code in (CONIC, BOX, POLYGON)


@pytest.mark.parametrize("spec", SPECS)
def test_bead_width_is_the_outline_s_extent_across_the_motion(spec):
    """The width across a move is the projection of the turned outline on the move's normal
    (exact for polygons and rectangles; within the inner/outer polygons for curves), for
    orifices offset and turned in the nozzle frame (their centres turn with the nozzle)."""
    noz = parse_nozzle(spec)
    rng = np.random.default_rng(7)
    for direction, angle in rng.uniform(-180, 180, (25, 2)):
        t = math.radians(direction)
        n = np.array([-math.sin(t), math.cos(t)])
        widths = []
        for mode in ("inner", "outer"):
            pts = shapely.get_coordinates(noz.outline(angle, quad_segs=256, mode=mode))
            proj = pts @ n
            widths.append(proj.max() - proj.min())
        w = noz.bead_width(direction, angle)
        assert widths[0] - 1e-9 <= w <= widths[1] + 1e-9


@pytest.mark.parametrize("spec", [s for s in SPECS if "polygon" not in s])
def test_compiled_bead_width_equals_python(spec):
    noz = parse_nozzle(spec)
    assert measures(noz.footprints)
    o = orifice_of(noz.footprints)
    rng = np.random.default_rng(11)
    for direction, angle in rng.uniform(-400, 400, (50, 2)):
        assert _bead_width(direction, angle, noz.mount_angle, *o) == \
            noz.bead_width(direction, angle)


def test_polygon_orifices_are_measured_in_python():
    assert not measures(parse_nozzle(SPECS[6]).footprints)


@pytest.mark.parametrize("spec", SPECS)
def test_convex_pieces_cover_the_footprint_exactly(spec):
    noz = parse_nozzle(spec)
    pieces = noz.convex_pieces()
    outline = noz.outline(0.0, quad_segs=64)
    union = shapely.union_all([p.polygon(quad_segs=64) for p in pieces])
    assert union.symmetric_difference(outline).area < 1e-9 * outline.area
    for p in pieces:
        poly = p.polygon(quad_segs=64)
        assert poly.convex_hull.area - poly.area < 1e-12


@pytest.mark.parametrize("spec", SPECS)
def test_support_is_the_largest_projection(spec):
    """h(u) of each convex piece against its dense outer/inner outlines."""
    rng = np.random.default_rng(5)
    a = rng.uniform(0, 2 * math.pi, 64)
    ux, uy = np.cos(a), np.sin(a)
    for piece in parse_nozzle(spec).convex_pieces():
        h = piece.support(ux, uy)
        lo = (shapely.get_coordinates(piece.polygon(quad_segs=256, mode="inner"))
              @ np.array([ux, uy])).max(axis=0)
        hi = (shapely.get_coordinates(piece.polygon(quad_segs=256, mode="outer"))
              @ np.array([ux, uy])).max(axis=0)
        assert np.all(lo - 1e-12 <= h) and np.all(h <= hi + 1e-12)


@pytest.mark.parametrize("spec", SPECS[:8])
def test_symmetry_maps_the_orifice_onto_itself(spec):
    f = parse_nozzle(spec).footprints[0]
    period = f.symmetry
    poly = f.polygon(quad_segs=64)
    if period < 360:
        turned = shapely.affinity.rotate(poly, period, origin=f.center)
        assert turned.symmetric_difference(poly).area < 1e-9
    else:  # no period is claimed: the polygons here have none of 90° or 180°
        for p in (90.0, 180.0):
            turned = shapely.affinity.rotate(poly, p, origin=f.center)
            assert turned.symmetric_difference(poly).area > 1e-4


@pytest.mark.parametrize("spec", SPECS[:8])
def test_inradius_and_erosion_lie_inside(spec):
    """The disk of :meth:`inradius` lies in the inner polygon; the eroded shape of
    :meth:`eroded`, grown back by the erosion, lies in the orifice."""
    f = parse_nozzle(spec).footprints[0]
    n = 4 * 16
    inner = f.polygon(quad_segs=16)
    r = f.inradius(n)
    if f.code == POLYGON:
        assert r is None and f.eroded(0.01) is None
        return
    assert Point(f.center).buffer(r * (1 - 1e-9), quad_segs=64).within(inner)
    d = 0.5 * min(f.a, f.b)
    a, b = f.eroded(d)
    smaller = type(f)(a, b, f.center, f.rotation)
    grown = smaller.polygon(quad_segs=128, mode="outer").buffer(d * (1 - 1e-6), quad_segs=32)
    assert grown.within(f.polygon(quad_segs=128, mode="outer"))


def test_only_circles_are_disks_and_round_nozzles_are_centred_circles():
    assert parse_nozzle("circle:d=0.4").footprints[0].disk == pytest.approx(0.2)
    assert parse_nozzle("circle:d=0.4").is_round
    assert not parse_nozzle("circle:d=0.4,x=0.1").is_round
    for spec in SPECS[2:8]:
        assert parse_nozzle(spec).footprints[0].disk is None

"""Each convention of printability.model.geometry's docstring, pinned by a test."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from shapely.geometry import Point, box

from printability.errors import InputError, ResourceError, UnknownOptionError
from printability.model.geometry import Grid, Raster, as_region, rotation_matrix
from printability.model.machine import parse_machine
from printability.model.nozzle import parse_nozzle
from printability.options import ENGINES, REGISTRIES


def test_angles_are_degrees_counter_clockwise():
    np.testing.assert_allclose(rotation_matrix(90) @ [1, 0], [0, 1], atol=1e-12)
    n = parse_nozzle("rect:w=2,h=0.5")
    minx, miny, maxx, maxy = n.outline(90).bounds
    assert (maxx - minx, maxy - miny) == pytest.approx((0.5, 2.0))


def test_nozzle_origin_is_the_rotation_axis():
    n = parse_nozzle("circle:d=1,x=3")
    c = n.outline(90).centroid
    assert (c.x, c.y) == pytest.approx((0.0, 3.0), abs=1e-9)
    assert n.radius == pytest.approx(3.5)
    assert not n.is_round and n.symmetry_period == 360.0


def test_mounting_angle_adds_to_the_machine_angle():
    a = parse_nozzle("ellipse:major=1,minor=0.4,angle=30").outline(15)
    b = parse_nozzle("ellipse:major=1,minor=0.4").outline(45)
    assert a.symmetric_difference(b).area < 1e-12


def test_grid_axis_order_rows_grow_with_y():
    g = Grid(10.0, 20.0, 0.5, nx=4, ny=3)
    assert g.shape == (3, 4)
    xs, ys = g.centers()
    assert xs[0] == pytest.approx(10.25) and ys[-1] == pytest.approx(21.25)
    data = np.zeros(g.shape, bool)
    data[2, 0] = True  # top-left pixel in y-up terms
    r = Raster(g, data)
    assert r.area() == pytest.approx(0.25)


def test_grid_covering_snaps_origin_and_refuses_huge():
    g = Grid.covering((0.13, 0.27, 1.0, 1.0), 0.1)
    assert g.x0 == pytest.approx(0.1) and g.y0 == pytest.approx(0.2)
    with pytest.raises(ResourceError, match="pixels"):
        Grid.covering((0, 0, 1000, 1000), 0.001, max_pixels=10**8)


def test_raster_must_match_its_grid():
    with pytest.raises(InputError, match="grid shape"):
        Raster(Grid(0, 0, 1, 3, 2), np.zeros((3, 2)))


def test_erosion_is_without_reflection():
    # P = {t : A + t ⊆ G}; with an offset nozzle the reflection matters.
    from shapely.affinity import translate

    g = box(0, 0, 10, 1)
    n = parse_nozzle("circle:d=1,x=2")
    fp = n.outline(0)
    assert translate(fp, 3, 0.5).within(g.buffer(1e-9))      # t = (3, .5): footprint at x 4.5..5.5
    assert not translate(fp, 8, 0.5).within(g)               # t = (8, .5): footprint at x 9.5..10.5


def test_region_repair_and_refusal():
    bowtie = shapely.Polygon([(0, 0), (1, 1), (1, 0), (0, 1)])
    r = as_region(bowtie)
    assert r.is_valid and r.area == pytest.approx(0.5)
    with pytest.raises(InputError, match="not a valid polygon"):
        as_region(bowtie, repair=False)
    with pytest.raises(InputError, match="empty"):
        as_region(shapely.Polygon())
    with pytest.raises(InputError, match="no area"):
        as_region(Point(0, 0).buffer(1).exterior)


@pytest.mark.parametrize("registry", list(REGISTRIES.values()), ids=list(REGISTRIES))
def test_unknown_option_lists_choices(registry):
    with pytest.raises(UnknownOptionError) as err:
        registry.check("no-such-thing")
    for choice in registry.choices:
        assert choice in str(err.value)


def test_every_engine_has_an_implementation():
    from printability.mmc import ENGINE_FUNCTIONS

    assert set(ENGINES.choices) - {"auto"} == set(ENGINE_FUNCTIONS)


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("circle:d=0", "positive"),
        ("circle:d=-1", "positive"),
        ("circle", "exactly one"),
        ("ellipse:major=0.3,minor=0.8", "larger than major"),
        ("ellipse:major=abc,minor=0.3", "expects a number"),
        ("hexagon:d=1", "expected one of"),
        ("rect:w=1,h=1,q=3", "unknown parameter"),
        ("polygon:pts=0 0;1 0", "at least 3"),
        ("", "non-empty"),
    ],
)
def test_bad_nozzle_specs(spec, message):
    with pytest.raises(InputError, match=message):
        parse_nozzle(spec)


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("ttr:min=90,max=-90", "below min"),
        ("ttr:step=0", "step"),
        ("ttr:min=-360,max=360", "full turn"),
        ("xy:step=1", "no parameters"),
        ("delta", "expected one of"),
        ("ttr:letter=Q", "rotary letter"),
    ],
)
def test_bad_machine_specs(spec, message):
    with pytest.raises(InputError, match=message):
        parse_machine(spec)


def test_machine_angles_use_nozzle_symmetry():
    m = parse_machine("ttr")
    assert len(m.angles(period=180)) == 90 and len(m.angles(period=360)) == 180
    assert list(m.angles(period=0)) == [-180.0]
    lim = parse_machine("ttr:min=-30,max=30,step=7")
    a = lim.angles(period=180)
    assert a[0] == -30 and a[-1] == pytest.approx(30) and np.all(np.diff(a) <= 7)


@pytest.mark.parametrize("name", ["polar", "scara", "ttr"])
def test_builtin_profiles_load(name):
    m = parse_machine(name)
    assert m.kind in ("chain", "ttr")


def test_chain_pose_polar():
    m = parse_machine("polar")
    phi, t = m.pose(np.array([[90.0, 10.0], [0.0, 5.0]]))
    np.testing.assert_allclose(phi, [90, 0])
    np.testing.assert_allclose(t, [[0, 10], [5, 0]], atol=1e-12)


def test_bead_width_of_ellipse_and_rect():
    e = parse_nozzle("ellipse:major=0.8,minor=0.3")
    assert e.bead_width(0) == pytest.approx(0.3)   # moving along the major axis
    assert e.bead_width(90) == pytest.approx(0.8)  # moving across it
    assert e.bead_width(0, angle=90) == pytest.approx(0.8)
    r = parse_nozzle("rect:w=2,h=1")
    assert r.bead_width(45) == pytest.approx(3 / np.sqrt(2))


def test_outline_modes_bracket_the_true_ellipse():
    n = parse_nozzle("ellipse:major=2,minor=1")
    inner, outer = n.outline(0, quad_segs=8, mode="inner"), n.outline(0, quad_segs=8, mode="outer")
    assert inner.area < n.area < outer.area
    assert inner.within(outer)


def test_auto_engine_choice():
    from printability.mmc import EXACT_VERTEX_LIMIT, choose_engine

    circle, ellipse = parse_nozzle("circle:d=0.4"), parse_nozzle("ellipse:major=0.8,minor=0.3")
    xy, ttr, polar = parse_machine("xy"), parse_machine("ttr"), parse_machine("polar")
    small = box(0, 0, 10, 10)
    big = Point(0, 0).buffer(10, quad_segs=EXACT_VERTEX_LIMIT // 4 + 10)
    assert choose_engine(circle, xy, small) == "exact"
    assert choose_engine(circle, ttr, small) == "exact"      # a round nozzle needs no angle
    assert choose_engine(circle, xy, big) == "raster"        # too many vertices for exact
    assert choose_engine(ellipse, xy, small) == "exact"
    assert choose_engine(ellipse, ttr, small) == "raster"
    assert choose_engine(ellipse, polar, small) == "sampled"


def test_which_machines_turn_which_nozzles_is_said_once():
    """Machine.turns: a rotary axis and a nozzle that is not round; covers_period: the
    range reaches every orientation of the nozzle."""
    from printability.model.machine import parse_machine
    from printability.model.nozzle import parse_nozzle

    ellipse, circle = parse_nozzle("ellipse:major=0.8,minor=0.3"), parse_nozzle("circle:d=0.4")
    ttr, xy = parse_machine("ttr"), parse_machine("xy")
    assert ttr.turns(ellipse) and not ttr.turns(circle)
    assert not xy.turns(ellipse) and not xy.turns(circle)
    assert ttr.covers_period(180.0) and ttr.covers_period(360.0)
    narrow = parse_machine("ttr:min=0,max=90")
    assert narrow.turns(ellipse) and not narrow.covers_period(180.0)
    assert narrow.covers_period(90.0) and not xy.covers_period(180.0)

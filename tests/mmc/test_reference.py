"""The reference engine (literal inverse trajectories) against closed forms, the MMC
promise checked independently with shapely, and the exact engine.

Its stated tolerance (module docstring): the bounds contain the exact lost area and are
about perimeter × (ε + ρ' + h) wide, ε = h/√2 + δ/2, ρ' = h/√2 (+ r·Δφ/2 when turning).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from shapely.geometry import MultiPolygon, box
from shapes import catalogue, rectangle, slot, strip, u_shape

from printability.errors import InputError, ResourceError
from printability.mmc import compute_mmc
from printability.mmc.reference import grid_rectangles, mmc_reference
from printability.model.geometry import as_region, polygons_of
from printability.model.machine import parse_machine
from printability.model.nozzle import parse_nozzle
from printability.settings import Settings

CATALOGUE = catalogue()


def reference(region, nozzle, machine="xy", **kw):
    return compute_mmc(region, nozzle, machine, engine="reference", settings=Settings(**kw))


def stated_width(res) -> float:
    """The module's stated width of the bounds: perimeter × (ε + ρ' + h), with margin."""
    h = res.resolution
    return 1.5 * res.target.length * (res.extra["grow"] + res.extra["shrink"] + h) + 1e-9


def check(res, exact_value):
    lo, hi = res.lost_area_bounds
    assert lo - 1e-9 <= exact_value <= hi + 1e-9, (lo, exact_value, hi)
    assert lo <= res.lost_area <= hi
    assert hi - lo <= stated_width(res)


def assert_mmc_promise(res, *, n_points: int = 400):
    """S ⊆ G, and the nozzle placed anywhere in the reported P (cell corners included)
    stays inside G: an independent shapely check."""
    g = res.target
    assert res.as_built.difference(g).area <= 1e-9
    rng = np.random.default_rng(1)
    for angle, region in zip(res.motion.angles, res.motion.regions, strict=True):
        if region.is_empty:
            continue
        pts = shapely.get_coordinates(region)
        if len(pts) > n_points:
            pts = pts[rng.choice(len(pts), n_points, replace=False)]
        outline = res.nozzle.outline(float(angle), mode="outer")
        for x, y in pts:
            placed = shapely.affinity.translate(outline, x, y)
            assert placed.difference(g).area <= 1e-12, (angle, x, y)


# ------------------------------------------------------------------ closed forms


@pytest.mark.parametrize("w,h,r", [(2.0, 2.0, 0.8), (4.0, 2.5, 0.5), (3.0, 1.0, 0.3)])
def test_rectangle_opened_by_a_disk_loses_4_minus_pi_r2(w, h, r):
    res = reference(rectangle(w, h), f"circle:r={r}", resolution=0.005)
    check(res, (4.0 - math.pi) * r * r)
    assert_mmc_promise(res)


def test_bounds_tighten_as_h_shrinks():
    widths = []
    for h in (0.04, 0.02, 0.01):
        res = reference(rectangle(2.0, 2.0), "circle:d=1.2", resolution=h)
        check(res, (4.0 - math.pi) * 0.36)
        widths.append(res.lost_area_bounds[1] - res.lost_area_bounds[0])
    assert widths[0] > widths[1] > widths[2]
    assert widths[2] < 0.4 * widths[0]


@pytest.mark.parametrize("spec", ["circle:d=0.6", "rect:w=0.6,h=0.6", "ellipse:major=1,minor=0.6"])
@pytest.mark.parametrize("machine", ["xy", "ttr:step=10"])
def test_strip_narrower_than_the_nozzle_vanishes(spec, machine):
    g = strip(0.5, 5.0)
    res = reference(g, spec, machine, resolution=0.02)
    assert res.as_built.is_empty
    assert all(r.is_empty for r in res.motion.regions)
    assert res.components.count == 0
    assert res.lost_area == pytest.approx(g.area)
    if machine == "xy":  # on a rotary axis the optimistic pass may shrink the nozzle enough
        assert res.lost_area_bounds == pytest.approx((g.area, g.area))


def test_ellipse_across_a_slot_prints_nothing_on_xy():
    # slot 0.5 wide, ellipse 0.8 × 0.3 turned so its major axis crosses the slot
    g = slot(0.5, 6.0)
    res = reference(g, "ellipse:major=0.8,minor=0.3,angle=90", "xy", resolution=0.01)
    assert res.as_built.is_empty
    assert res.lost_area_bounds == pytest.approx((g.area, g.area))


def test_ellipse_in_a_slot_prints_the_slot_on_ttr():
    g = slot(0.5, 6.0)
    res = reference(g, "ellipse:major=0.8,minor=0.3", "ttr:step=5", resolution=0.01)
    assert res.lost_area < 0.03 * g.area
    # the whole channel away from its two ends is printed
    assert res.as_built.contains(box(-2.5, -0.2, 2.5, 0.2))
    assert res.components.count == 1
    assert_mmc_promise(res, n_points=100)
    # the ellipse's width across the slot, 2·√(a²sin²θ + b²cos²θ), is below 0.5 for
    # θ < 32.6°: with 5° steps, 30° is the last angle that fits
    fits = [a for a, r in zip(res.motion.angles, res.motion.regions, strict=True)
            if not r.is_empty]
    off = [min(abs(a % 180), 180 - abs(a % 180)) for a in fits]
    assert 30.0 <= max(off) < 32.6


def test_limited_rotary_range_agrees_with_the_exact_engine():
    g = slot(0.5, 6.0, angle=20.0)
    spec, machine = "ellipse:major=0.8,minor=0.3", "ttr:min=-30,max=30,step=10"
    ref = reference(g, spec, machine, resolution=0.02)
    ex = compute_mmc(g, spec, machine, engine="exact")
    lo, hi = ref.lost_area_bounds
    elo, ehi = ex.lost_area_bounds
    assert lo <= ehi + 1e-9 and elo <= hi + 1e-9
    np.testing.assert_allclose(ref.motion.angles, [-30, -20, -10, 0, 10, 20, 30])
    # turned by 20°, the slot is reached from 0° to 30° only (and -10° with 30° off-axis)
    fits = [a for a, r in zip(ref.motion.angles, ref.motion.regions, strict=True)
            if not r.is_empty]
    assert min(fits) >= -10.0


def test_u_shape_components():
    # arms 4 mm wide, base 2 mm: a 2.5 mm disk fits each arm, not the base
    assert reference(u_shape(), "circle:d=2.5", resolution=0.04).components.count == 2
    one = reference(u_shape(), "circle:d=1", resolution=0.04)
    assert one.components.count == 1
    assert one.components.geometries[0].area > 0


def test_multi_orifice_head_keeps_every_orifice_inside():
    # two pads 4 mm apart, joined by a thin bridge: a head with two orifices 4 mm apart
    g = as_region(shapely.union_all([box(0, 0, 2, 2), box(4, 0, 6, 2), box(2, 0.9, 4, 1.1)]))
    res = reference(g, "circle:d=0.5,x=-2+circle:d=0.5,x=2", resolution=0.02)
    assert not res.as_built.is_empty
    assert_mmc_promise(res)
    # the head can only sit where both orifices are on a pad: around x = 3
    for piece in polygons_of(res.motion.regions[0]):
        minx, _, maxx, _ = piece.bounds
        assert 2.2 <= minx and maxx <= 3.8


# ------------------------------------------------------------------ the exact engine


def _overlap(a, b):
    alo, ahi = a.lost_area_bounds
    blo, bhi = b.lost_area_bounds
    assert alo <= bhi + 1e-9 and blo <= ahi + 1e-9, (a.lost_area_bounds, b.lost_area_bounds)


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_agrees_with_the_exact_and_raster_engines_on_the_catalogue(name):
    g = CATALOGUE[name].region
    ex = compute_mmc(g, "circle:d=0.6", "xy", engine="exact")
    ras = compute_mmc(g, "circle:d=0.6", "xy", engine="raster",
                      settings=Settings(resolution=0.04))
    ref = reference(g, "circle:d=0.6", "xy", resolution=0.04)
    _overlap(ex, ref)
    _overlap(ras, ref)
    assert ref.as_built.difference(g).area <= 1e-9
    # what the reference promises lies inside what the exact engine says is printable
    assert ref.as_built.difference(ex.as_built.buffer(1e-6)).area <= 1e-6


@pytest.mark.parametrize("name", ["rectangle", "slot_30deg"])
def test_agrees_with_the_exact_engine_on_ttr(name):
    g = CATALOGUE[name].region
    spec, machine = "ellipse:major=0.8,minor=0.3", "ttr:step=15"
    ex = compute_mmc(g, spec, machine, engine="exact")
    ref = reference(g, spec, machine, resolution=0.04)
    _overlap(ex, ref)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(CATALOGUE))
@pytest.mark.parametrize("spec,machine", [("circle:d=0.6", "xy"),
                                          ("ellipse:major=0.8,minor=0.3", "ttr:step=15"),
                                          ("rect:w=0.8,h=0.4", "ttr:step=10")])
def test_agrees_with_the_exact_engine_fine(name, spec, machine):
    g = CATALOGUE[name].region
    _overlap(compute_mmc(g, spec, machine, engine="exact"),
             reference(g, spec, machine, resolution=0.02))


# ------------------------------------------------------------------ properties


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(w=st.floats(1.0, 3.0), h=st.floats(1.0, 3.0), frac=st.floats(0.1, 0.45))
def test_random_rectangles_contain_the_closed_form(w, h, frac):
    r = frac * min(w, h)
    res = reference(rectangle(w, h), f"circle:r={r}", resolution=0.02)
    check(res, (4.0 - math.pi) * r * r)


def test_grid_rectangles_cover_exactly_the_cells():
    rng = np.random.default_rng(3)
    mask = rng.random((30, 40)) < 0.6
    xs, ys = np.arange(40) * 0.5, np.arange(30) * 0.5
    rects = grid_rectangles(mask, xs, ys, 0.5)
    union = shapely.union_all(shapely.box(*rects.T))
    assert union.area == pytest.approx(mask.sum() * 0.25)
    cells = shapely.union_all([box(xs[j] - 0.25, ys[i] - 0.25, xs[j] + 0.25, ys[i] + 0.25)
                               for i, j in zip(*np.nonzero(mask), strict=True)])
    assert union.symmetric_difference(cells).area < 1e-9


# ------------------------------------------------------------------ bad input


def test_refuses_a_chain_machine():
    with pytest.raises(InputError, match="separable"):
        mmc_reference(as_region(rectangle()), parse_nozzle("circle:d=1"), parse_machine("polar"))


def test_refuses_too_much_work_before_doing_it():
    with pytest.raises(ResourceError, match="coarser resolution"):
        mmc_reference(as_region(rectangle(10, 10)), parse_nozzle("circle:d=1"),
                      parse_machine("xy"), settings=Settings(resolution=0.001), max_work=1e6)


@pytest.mark.parametrize("spacing", [0.0, -1.0, float("nan")])
def test_refuses_a_bad_boundary_spacing(spacing):
    with pytest.raises(InputError, match="boundary_spacing"):
        mmc_reference(as_region(rectangle()), parse_nozzle("circle:d=1"), parse_machine("xy"),
                      boundary_spacing=spacing)


def test_no_lower_bound_when_the_lattice_is_coarser_than_the_nozzle():
    res = reference(rectangle(4.0, 4.0), "circle:d=0.1", resolution=0.2)
    assert res.lost_area_bounds[0] == 0.0
    assert any("no lower bound" in n for n in res.notes)


def test_result_is_empty_geometry_when_nothing_fits():
    res = reference(rectangle(1.0, 0.3), "circle:d=0.28,x=0.5", resolution=0.02)
    assert isinstance(res.as_built, MultiPolygon)
    assert res.lost_area == pytest.approx(res.target_area)


_NOZZLES = ["circle:d=0.5", "ellipse:major=0.9,minor=0.3,angle=25", "rect:w=0.8,h=0.3,rot=10",
            "polygon:pts=0 0;0.8 0;0.8 0.25;0.25 0.25;0.25 0.7;0 0.7",
            "circle:d=0.3,x=-0.5+ellipse:major=0.5,minor=0.2,x=0.5"]


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(spec=st.sampled_from(_NOZZLES),
       boxes=st.lists(st.tuples(st.floats(0, 3), st.floats(0, 3), st.floats(0.5, 2.5),
                                st.floats(0.5, 2.5)), min_size=1, max_size=3),
       hole=st.tuples(st.floats(0.5, 3.5), st.floats(0.5, 3.5), st.floats(0.1, 0.6)))
def test_random_regions_keep_the_promise_and_agree_with_exact(spec, boxes, hole):
    g = shapely.union_all([box(x, y, x + w, y + h) for x, y, w, h in boxes])
    g = g.difference(shapely.Point(hole[0], hole[1]).buffer(hole[2], quad_segs=8))
    if g.area < 0.5:
        return
    g = as_region(g)
    res = reference(g, spec, resolution=0.04)
    assert_mmc_promise(res, n_points=150)
    ex = compute_mmc(g, spec, "xy", engine="exact")
    _overlap(ex, res)

"""The sampled engine (any machine chain) against closed forms, the separable engines on
XY and T-T-R, and the MMC promise on the polar and SCARA machines (checked with poses
and shapely placements computed here, independently of the engine)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import shapely
import shapely.affinity
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy import ndimage
from shapely.geometry import MultiPolygon, Point, box
from shapes import catalogue, rectangle, slot, strip

from printability.errors import ResourceError
from printability.mmc import compute_mmc
from printability.mmc.sampled import mmc_sampled, sample_space
from printability.model.geometry import as_region
from printability.model.machine import Joint, parse_machine
from printability.model.nozzle import parse_nozzle
from printability.settings import Settings

CATALOGUE = catalogue()


def sampled(region, nozzle, machine="xy", **kw):
    return compute_mmc(region, nozzle, machine, engine="sampled", settings=Settings(**kw))


def polar(r_max: float = 4.0, b_step: float = 1.0, r_step: float = 0.05):
    """The shipped polar printer with a short arm (fast tests)."""
    m = parse_machine("polar")
    return replace(m, joints=(Joint("B", "revolute", -180.0, 180.0, b_step),
                              Joint("R", "prismatic", 0.0, r_max, r_step)))


def scara(step: float = 0.5):
    m = parse_machine("scara")
    j = m.joints
    return replace(m, joints=(replace(j[0], step=step), replace(j[1], step=step)))


def polar_pose(u):
    """Polar kinematics written out: the nozzle at radius R along B, turned by B."""
    b, r = np.deg2rad(u[:, 0]), u[:, 1]
    return u[:, 0], np.column_stack([r * np.cos(b), r * np.sin(b)])


def scara_pose(u):
    """SCARA kinematics written out: base (0, −90), arms 100 and 80 mm, no wrist."""
    s, e = np.deg2rad(u[:, 0]), np.deg2rad(u[:, 0] + u[:, 1])
    x = 100 * np.cos(s) + 80 * np.cos(e)
    y = -90 + 100 * np.sin(s) + 80 * np.sin(e)
    return u[:, 0] + u[:, 1], np.column_stack([x, y])


def assert_feasible_really_inside(res, pose, *, n: int = 300):
    """Every reported feasible configuration keeps the footprint inside G.

    The footprint is placed as its outer polygon (which contains it); G is allowed the
    polygon's own excess over the true curve (a·(1/cos(π/n) − 1), n = 128 vertices).
    """
    excess = max(f.a for f in res.nozzle.footprints) * (1 / math.cos(math.pi / 128) - 1)
    g = res.target.buffer(excess + 1e-9)
    samples = res.motion.samples
    assert len(samples) > 0
    rng = np.random.default_rng(0)
    pick = samples[rng.choice(len(samples), min(n, len(samples)), replace=False)]
    phi, t = pose(pick)
    for a, (x, y) in zip(phi, t, strict=True):
        placed = shapely.affinity.translate(res.nozzle.outline(float(a), mode="outer"), x, y)
        assert g.contains(placed), (a, x, y)
    assert res.as_built.difference(res.target).area <= 1e-9


def xy_pose(u):
    return (u[:, 2] if u.shape[1] > 2 else np.zeros(len(u))), u[:, :2]


def _overlap(a, b):
    alo, ahi = a.lost_area_bounds
    blo, bhi = b.lost_area_bounds
    assert alo <= bhi + 1e-9 and blo <= ahi + 1e-9, (a.lost_area_bounds, b.lost_area_bounds)


# ------------------------------------------------------------------ XY and T-T-R


@pytest.mark.parametrize("w,h,r", [(2.0, 2.0, 0.8), (4.0, 2.5, 0.5)])
def test_rectangle_opened_by_a_disk_loses_4_minus_pi_r2(w, h, r):
    res = sampled(rectangle(w, h), f"circle:r={r}", resolution=0.01)
    lo, hi = res.lost_area_bounds
    assert lo <= (4 - math.pi) * r * r <= hi
    assert lo <= res.lost_area <= hi
    # stated tolerance: lattice step plus slack L = h/√2 on each side, along the perimeter
    assert hi - lo <= 1.5 * res.target.length * (0.01 + 2 * res.extra["slack"])
    assert_feasible_really_inside(res, xy_pose)


@pytest.mark.parametrize("spec", ["circle:d=0.6", "rect:w=0.6,h=0.6", "ellipse:major=1,minor=0.6"])
@pytest.mark.parametrize("machine", ["xy", "ttr:step=10"])
def test_strip_narrower_than_the_nozzle_vanishes(spec, machine):
    g = strip(0.5, 5.0)
    res = sampled(g, spec, machine, resolution=0.02)
    assert res.as_built.is_empty and len(res.motion.samples) == 0
    assert res.components.count == 0
    assert res.lost_area == pytest.approx(g.area)


def test_ellipse_across_a_slot_prints_nothing_on_xy():
    g = slot(0.5, 6.0)
    res = sampled(g, "ellipse:major=0.8,minor=0.3,angle=90", "xy", resolution=0.01)
    assert res.as_built.is_empty
    assert res.lost_area_bounds == pytest.approx((g.area, g.area))


def test_ellipse_in_a_slot_prints_the_slot_on_ttr():
    g = slot(0.5, 6.0)
    res = sampled(g, "ellipse:major=0.8,minor=0.3", "ttr:step=5", resolution=0.01)
    assert res.lost_area < 0.03 * g.area
    assert res.as_built.contains(box(-2.5, -0.2, 2.5, 0.2))
    assert res.components.count == 1
    assert_feasible_really_inside(res, xy_pose)
    # 30° fits (width across the slot 0.477 mm), 35° does not (0.519 mm)
    off = np.abs(((res.motion.samples[:, 2] + 90) % 180) - 90)
    assert off.max() == pytest.approx(30.0)


def test_limited_rotary_range_samples_both_ends():
    g = slot(0.5, 6.0)
    res = sampled(g, "ellipse:major=0.8,minor=0.3", "ttr:min=-30,max=30,step=10",
                  resolution=0.02)
    angles = np.unique(res.motion.samples[:, 2])
    np.testing.assert_allclose(angles, [-30, -20, -10, 0, 10, 20, 30])
    assert res.components.count == 1
    assert res.lost_area < 0.05 * g.area


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_agrees_with_the_exact_and_raster_engines_on_xy(name):
    g = CATALOGUE[name].region
    ex = compute_mmc(g, "circle:d=0.6", "xy", engine="exact")
    ras = compute_mmc(g, "circle:d=0.6", "xy", engine="raster",
                      settings=Settings(resolution=0.04))
    res = sampled(g, "circle:d=0.6", "xy", resolution=0.04)
    _overlap(ex, res)
    _overlap(ras, res)
    assert res.as_built.difference(g).area <= 1e-9


@pytest.mark.parametrize("name", ["rectangle", "u_shape"])
def test_agrees_with_the_exact_and_reference_engines_on_ttr(name):
    g = CATALOGUE[name].region
    spec, machine = "ellipse:major=0.8,minor=0.3", "ttr:step=15"
    ex = compute_mmc(g, spec, machine, engine="exact")
    ref = compute_mmc(g, spec, machine, engine="reference", settings=Settings(resolution=0.04))
    res = sampled(g, spec, machine, resolution=0.04)
    _overlap(ex, res)
    _overlap(ref, res)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(CATALOGUE))
@pytest.mark.parametrize("spec,machine", [("ellipse:major=0.8,minor=0.3", "ttr:step=15"),
                                          ("rect:w=0.8,h=0.4", "ttr:step=10")])
def test_agrees_with_the_exact_engine_on_ttr_fine(name, spec, machine):
    g = CATALOGUE[name].region
    _overlap(compute_mmc(g, spec, machine, engine="exact"),
             sampled(g, spec, machine, resolution=0.02))


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(w=st.floats(1.0, 3.0), h=st.floats(1.0, 3.0), frac=st.floats(0.1, 0.45))
def test_random_rectangles_contain_the_closed_form(w, h, frac):
    r = frac * min(w, h)
    res = sampled(rectangle(w, h), f"circle:r={r}", resolution=0.02)
    lo, hi = res.lost_area_bounds
    assert lo - 1e-9 <= (4 - math.pi) * r * r <= hi + 1e-9


# ------------------------------------------------------------------ polar printer


@pytest.mark.parametrize("spec", ["circle:d=0.4", "ellipse:major=0.8,minor=0.3"])
def test_disk_centred_on_the_polar_axis_is_printed(spec):
    g = as_region(Point(0, 0).buffer(3.0, quad_segs=64))
    res = mmc_sampled(g, parse_nozzle(spec), polar())
    ex = compute_mmc(g, spec, "xy", engine="exact")  # a disk turns freely in a disk
    lo, hi = res.lost_area_bounds
    assert lo <= ex.lost_area_bounds[1] + 1e-9
    # only a rim thinner than the arm's step is lost
    assert hi < g.length * 0.06
    assert res.components.count == 1
    assert res.as_built.contains(Point(0, 0).buffer(2.9))
    assert_feasible_really_inside(res, polar_pose)


def test_polar_components_wrap_across_the_half_turn():
    # a part on the negative x axis: B near +180° and near −180°, the two ends of the grid
    g = as_region(box(-4.0, -0.5, -2.0, 0.5))
    res = mmc_sampled(g, parse_nozzle("circle:d=0.4"), polar())
    _, raw = ndimage.label(res.extra["feasible"])
    assert raw == 2            # split by the ends of the B range...
    assert res.components.count == 1   # ...which meet on a full turn
    assert_feasible_really_inside(res, polar_pose)


# ------------------------------------------------------------------ SCARA arm


def test_scara_reaches_a_part_with_two_elbow_branches():
    g = as_region(Point(0, 60).buffer(2.0, quad_segs=32))
    res = mmc_sampled(g, parse_nozzle("circle:d=0.4"), scara())
    assert res.components.count == 2  # elbow left and elbow right
    e = res.motion.samples[:, 1]
    assert (e > 0).any() and (e < 0).any()
    lo, hi = res.lost_area_bounds
    assert lo <= res.lost_area <= hi
    assert_feasible_really_inside(res, scara_pose)


def test_part_out_of_scara_reach_prints_nothing():
    g = as_region(Point(500, 500).buffer(10.0))
    res = mmc_sampled(g, parse_nozzle("circle:d=0.4"), parse_machine("scara"))
    assert isinstance(res.as_built, MultiPolygon) and res.as_built.is_empty
    assert res.lost_area == pytest.approx(g.area)
    assert res.lost_area_bounds == pytest.approx((g.area, g.area))
    assert res.components.count == 0 and len(res.motion.samples) == 0
    assert any("out of the machine's reach" in n for n in res.notes)


# ------------------------------------------------------------------ limits


def test_refuses_too_many_samples_before_sampling():
    with pytest.raises(ResourceError, match="coarser joint steps"):
        mmc_sampled(as_region(rectangle()), parse_nozzle("circle:d=0.4"),
                    parse_machine("polar"), max_samples=10_000)


def test_sample_space_slack_bounds_the_motion_between_samples():
    # a configuration half a step from a sample in every joint moves the nozzle by <= L
    m = polar(r_max=10.0, b_step=2.0, r_step=0.1)
    noz = parse_nozzle("ellipse:major=0.8,minor=0.3")
    space = sample_space(as_region(rectangle()), noz, m, settings=Settings())
    rng = np.random.default_rng(5)
    u0 = np.column_stack([rng.choice(space.values[0], 200), rng.choice(space.values[1], 200)])
    u1 = u0 + rng.uniform(-0.5, 0.5, u0.shape) * np.array(space.steps)
    u1[:, 1] = np.clip(u1[:, 1], 0.0, 10.0)
    pts = np.asarray(noz.outline(0.0).exterior.coords)
    for a, b in zip(u0, u1, strict=True):
        (pa,), (ta,) = polar_pose(a[None])
        (pb,), (tb,) = polar_pose(b[None])
        ra, rb = np.deg2rad(pa), np.deg2rad(pb)
        qa = pts @ np.array([[np.cos(ra), np.sin(ra)], [-np.sin(ra), np.cos(ra)]]) + ta
        qb = pts @ np.array([[np.cos(rb), np.sin(rb)], [-np.sin(rb), np.cos(rb)]]) + tb
        assert np.hypot(*(qa - qb).T).max() <= space.slack + 1e-12


# ------------------------------------------------------------------ the containment test


_NOZZLES = ["circle:d=0.5", "ellipse:major=0.9,minor=0.3,angle=25", "rect:w=0.8,h=0.3,rot=10",
            "polygon:pts=0 0;0.8 0;0.8 0.25;0.25 0.25;0.25 0.7;0 0.7",
            "circle:d=0.3,x=-0.5+ellipse:major=0.5,minor=0.2,x=0.5"]


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(spec=st.sampled_from(_NOZZLES),
       boxes=st.lists(st.tuples(st.floats(0, 3), st.floats(0, 3), st.floats(0.5, 2.5),
                                st.floats(0.5, 2.5)), min_size=1, max_size=3),
       hole=st.tuples(st.floats(0.5, 3.5), st.floats(0.5, 3.5), st.floats(0.1, 0.6)),
       turn=st.booleans())
def test_every_sample_is_decided_like_shapely(spec, boxes, hole, turn):
    """Feasible samples have the nozzle inside G, infeasible ones do not (up to the
    polygons' own approximation of curved orifices): random regions with holes and
    random nozzles, every grid sample checked against shapely placements."""
    g = shapely.union_all([box(x, y, x + w, y + h) for x, y, w, h in boxes])
    g = g.difference(Point(hole[0], hole[1]).buffer(hole[2], quad_segs=8))
    if g.area < 0.5:
        return
    g = as_region(g)
    machine = "ttr:step=45" if turn else "xy"
    res = sampled(g, spec, machine, resolution=0.1)
    noz = res.nozzle
    curved = [f.a for f in noz.footprints if f.kind in ("circle", "ellipse")]
    err = max(curved, default=0.0) * (1 / math.cos(math.pi / 128) - 1) + 1e-7
    grown, shrunk = g.buffer(err), g.buffer(-err)
    feas = res.extra["feasible"]
    vals = res.extra["joint_values"]
    rng = np.random.default_rng(0)
    flat = rng.choice(feas.size, min(300, feas.size), replace=False)
    idx = np.unravel_index(flat, feas.shape)
    u = np.column_stack([v[i] for v, i in zip(vals, idx, strict=True)])
    for k in range(len(u)):
        a = float(u[k, 2]) if u.shape[1] > 2 else 0.0
        if feas[tuple(i[k] for i in idx)]:
            placed = shapely.affinity.translate(noz.outline(a, mode="outer"), *u[k, :2])
            assert grown.contains(placed), (spec, u[k])
        else:
            placed = shapely.affinity.translate(noz.outline(a, mode="inner"), *u[k, :2])
            assert not shrunk.contains_properly(placed) or shrunk.is_empty, (spec, u[k])

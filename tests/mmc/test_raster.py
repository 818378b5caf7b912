"""The raster MMC engine: closed forms, proven bounds, MMC safety, kernels, memory refusal."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from shapely import affinity
from shapely.geometry import MultiPolygon, Point, Polygon, box

from printability.errors import InputError, ResourceError
from printability.mmc import _raster_kernels as rk
from printability.mmc import compute_mmc
from printability.mmc._raster_passes import _mask_runs, opening_pass
from printability.mmc._raster_runs import extract_runs, label_runs
from printability.mmc.raster import (
    _erode3,
    mmc_raster,
    prepare_raster,
    rasterize_region,
)
from printability.model.geometry import Grid, as_region
from printability.model.machine import parse_machine
from printability.model.nozzle import parse_nozzle
from printability.settings import Settings


def raster(region, nozzle, machine="xy", h=0.02, **kw):
    return compute_mmc(region, nozzle, machine, engine="raster",
                       settings=Settings(resolution=h, **kw))


def corner_loss(poly: Polygon, a: float, b: float, rot_deg: float) -> float:
    """Exact lost area of a polygon opened by an ellipse (a, b) turned by rot_deg.

    Affine trick: with L = R(rot)·diag(a, b), opening(G, L·D) = L·opening(L⁻¹G, D).
    A unit disk opening loses cot(θ/2) − (π − θ)/2 at every convex corner of
    interior angle θ (nothing at reflex corners), when the disk fits everywhere
    and corners are far apart; areas scale by det L = ab.
    """
    c, s = math.cos(math.radians(rot_deg)), math.sin(math.radians(rot_deg))
    inv = np.linalg.inv(np.array([[c, -s], [s, c]]) @ np.diag([a, b]))
    mapped = affinity.affine_transform(poly, [*inv.ravel(), 0, 0])
    total = 0.0
    # holes' corners are reflex seen from the region: only the CCW shell's left turns lose
    pts = np.asarray(shapely.geometry.polygon.orient(mapped, 1.0).exterior.coords)[:-1]
    n = len(pts)
    for i in range(n):
        u = pts[i] - pts[i - 1]
        v = pts[(i + 1) % n] - pts[i]
        cross = u[0] * v[1] - u[1] * v[0]
        if cross > 1e-12:
            theta = math.pi - abs(math.atan2(cross, float(np.dot(u, v))))
            total += 1.0 / math.tan(theta / 2) - (math.pi - theta) / 2
    return total * a * b


# Shapes whose disk/ellipse opening is known in closed form (features wider than the nozzle).
CATALOGUE = {
    "rectangle": box(0, 0, 3, 2),
    "square_rotated": affinity.rotate(box(0, 0, 2.5, 2.5), 17, origin=(0, 0)),
    "triangle": Polygon([(0, 0), (4, 0), (2, 2 * math.sqrt(3))]),
    "hexagon": Polygon([(2 * math.cos(t), 2 * math.sin(t))
                        for t in np.linspace(0, 2 * math.pi, 7)[:-1]]),
    "l_shape": Polygon([(0, 0), (4, 0), (4, 1.5), (1.5, 1.5), (1.5, 4), (0, 4)]),
    "frame": Polygon(box(0, 0, 4, 4).exterior, [box(1.5, 1.5, 2.5, 2.5).exterior.coords[::-1]]),
}


# ----------------------------------------------------------------------------- closed forms


@pytest.mark.parametrize("h", [0.05, 0.02, 0.01])
def test_rectangle_opened_by_disk_loses_4_minus_pi_r2(h):
    r = 0.5
    res = raster(box(0, 0, 3, 2), "circle:d=1", h=h)
    exact = (4 - math.pi) * r * r
    lo, hi = res.lost_area_bounds
    assert lo <= exact <= hi
    assert lo <= res.lost_area <= hi
    assert res.engine == "raster" and res.resolution == h


def test_estimate_and_bounds_converge_as_h_shrinks():
    exact = (4 - math.pi) * 0.25
    widths, errors = [], []
    for h in (0.04, 0.02, 0.01):
        res = raster(box(0, 0, 3, 2), "circle:d=1", h=h)
        lo, hi = res.lost_area_bounds
        widths.append(hi - lo)
        errors.append(abs(res.lost_area - exact))
    # the interval is O(perimeter·h): it halves with h (up to rasterisation noise)
    assert widths[1] < 0.7 * widths[0] and widths[2] < 0.7 * widths[1]
    assert errors[-1] < 0.05 * exact


@pytest.mark.parametrize("name", sorted(CATALOGUE))
@pytest.mark.parametrize("nozzle,a,b,rot", [
    ("circle:d=0.8", 0.4, 0.4, 0.0),
    ("ellipse:major=1,minor=0.5,angle=30", 0.5, 0.25, 30.0),
])
def test_catalogue_bounds_contain_closed_form(name, nozzle, a, b, rot):
    g = CATALOGUE[name]
    exact = corner_loss(g, a, b, rot)
    res = raster(g, nozzle, h=0.025)
    lo, hi = res.lost_area_bounds
    assert lo <= exact <= hi, (name, lo, exact, hi)
    assert res.as_built_area == pytest.approx(res.target_area - res.lost_area)
    # the estimate is within a few pixels' worth of perimeter of the exact value
    assert abs(res.lost_area - exact) <= 0.5 * g.length * 0.025


def test_strip_narrower_than_the_nozzle_vanishes():
    res = raster(box(0, 0, 10, 0.8), "circle:d=1", h=0.02)
    assert res.as_built_area == 0.0
    assert res.lost_area == pytest.approx(res.target_area)
    assert res.lost_area_bounds[0] == pytest.approx(res.target_area)
    assert not res.motion.count.data.any()
    assert res.components.count == 0


def test_ellipse_in_a_slot_xy_across_prints_nothing_ttr_prints_the_slot():
    slot = box(0, 0, 12, 1.1)  # width between minor 0.6 and major 1.6
    across = raster(slot, "ellipse:major=1.6,minor=0.6,angle=90", "xy", h=0.02)
    assert across.as_built_area == 0.0
    assert across.lost_area_bounds[0] == pytest.approx(slot.area)
    turning = raster(slot, "ellipse:major=1.6,minor=0.6", "ttr", h=0.02, angle_step=5.0)
    hi = turning.lost_area_bounds[1]
    assert hi < 0.25 * slot.area  # provably most of the slot prints
    assert turning.lost_fraction < 0.05
    # only near-axial angles fit: the count raster never exceeds the fitting angles
    fits = turning.motion.count.data.max()
    assert 0 < fits < len(turning.motion.angles)


def test_xy_single_angle_and_round_nozzle_on_ttr():
    res = raster(box(0, 0, 2, 2), "circle:d=0.5", "ttr", h=0.02)
    assert len(res.motion.angles) == 1 and res.angle_step == 0.0
    assert res.extra["angular_margin"] == 0.0


# ----------------------------------------------------------------------------- safety


@pytest.mark.parametrize("nozzle,machine", [
    ("ellipse:major=1.2,minor=0.4", "ttr:step=15"),
    ("rect:w=0.9,h=0.3,angle=10", "xy"),
    ("circle:d=0.4,x=0.5", "ttr:step=30"),  # offset orifice: P lies off the orifice
    ("circle:d=0.3,x=-0.6+circle:d=0.3,x=0.6", "ttr:step=30"),  # two orifices
])
def test_inner_motion_never_puts_the_true_footprint_outside(nozzle, machine):
    g = as_region(CATALOGUE["l_shape"].union(Point(5.5, 1).buffer(0.9)))
    res = raster(g, nozzle, machine, h=0.03)
    noz = parse_nozzle(nozzle)
    rng = np.random.default_rng(0)
    grid = res.motion.packed.grid
    xs, ys = grid.centers()
    checked = 0
    for k in range(0, len(res.motion.angles), max(1, len(res.motion.angles) // 4)):
        mask = res.motion.mask(k).data
        ii, jj = np.nonzero(mask)
        assert len(ii), "the test shape admits the nozzle at every angle"
        pick = rng.choice(len(ii), size=min(60, len(ii)), replace=False)
        # the outer polygon contains the true footprint
        fp = noz.outline(float(res.motion.angles[k]), quad_segs=64, mode="outer")
        placed = [affinity.translate(fp, xs[jj[p]], ys[ii[p]]) for p in pick]
        assert shapely.contains(g, placed).all()
        checked += len(pick)
    assert checked > 0


def test_as_built_is_inside_the_region_and_matches_its_raster():
    g = as_region(CATALOGUE["frame"])
    res = raster(g, "ellipse:major=0.8,minor=0.3", "ttr:step=20", h=0.03)
    assert g.buffer(1e-9).contains(res.as_built)
    assert res.as_built.area == pytest.approx(res.as_built_raster.area(), rel=1e-9)
    assert res.extra["inner_as_built_area"] == pytest.approx(res.as_built.area, rel=1e-9)


def test_ttr_bounds_cover_angles_between_samples():
    """A coarse angle step must widen the interval to still contain a fine-step estimate."""
    g = CATALOGUE["hexagon"]
    fine = raster(g, "ellipse:major=1.2,minor=0.4", "ttr:step=1", h=0.02)
    coarse = raster(g, "ellipse:major=1.2,minor=0.4", "ttr:step=30", h=0.02)
    assert coarse.extra["angular_margin"] > fine.extra["angular_margin"] > 0
    lo, hi = coarse.lost_area_bounds
    # the continuous lost area lies in both intervals, so they overlap
    assert lo <= fine.lost_area_bounds[1] and fine.lost_area_bounds[0] <= hi


# ----------------------------------------------------------------------------- results


def test_motion_restriction_fields_and_count():
    res = raster(CATALOGUE["l_shape"], "ellipse:major=1,minor=0.4", "ttr:step=15", h=0.04)
    m = res.motion
    n = len(m.angles)
    assert m.packed is not None and len(m.packed) == n
    stack = np.stack([m.packed.mask(k).data for k in range(n)])
    assert np.array_equal(m.count.data, stack.sum(axis=0))
    assert m.masks is not None and np.array_equal(m.masks.data, stack)
    assert np.array_equal(m.positions().data, m.packed.any().data)
    # point queries agree with the masks
    ii, jj = np.nonzero(stack[3])
    xs, ys = m.packed.grid.centers()
    assert m.packed.contains(3, xs[jj], ys[ii]).all()
    assert res.components.count == 1
    assert len(res.components.geometries) == 1
    lo_a, hi_a = res.components.angle_ranges[0]
    assert lo_a == m.angles.min() and hi_a == m.angles.max()


def test_components_separate_regions_and_angle_links():
    two = MultiPolygon([box(0, 0, 2, 2), box(3, 0, 5, 2)])
    res = raster(two, "circle:d=0.6", "xy", h=0.04)
    assert res.components.count == 2
    # a neck only the turned ellipse passes: one component over angles on T-T-R
    dumbbell = as_region(box(0, 0, 2, 2).union(box(4, 0, 6, 2)).union(box(1.9, 0.8, 4.1, 1.3)))
    ttr = raster(dumbbell, "ellipse:major=1.2,minor=0.4", "ttr:step=10", h=0.04)
    assert ttr.components.count == 1
    xy = raster(dumbbell, "ellipse:major=1.2,minor=0.4,angle=90", "xy", h=0.04)
    assert xy.components.count == 2


def test_run_labels_match_scipy_label():
    from scipy import ndimage

    rng = np.random.default_rng(3)
    for _ in range(5):
        mask = ndimage.binary_opening(rng.random((70, 150)) > 0.45)
        rr, rs, re = extract_runs(rk.pack_bits(mask), mask.shape[1])
        labels, count = label_runs(rr, rs, re)
        ref, nref = ndimage.label(mask)
        assert count == nref
        ours = np.full(mask.shape, -1)
        for r, s, e, lab in zip(rr, rs, re, labels, strict=True):
            ours[r, s:e] = lab
        # same partition: a bijection between our labels and scipy's
        pairs = {(a, b) for a, b in zip(ours[mask], ref[mask], strict=True)}
        assert len(pairs) == count


def test_bad_input_and_memory_refusal():
    with pytest.raises(InputError):
        mmc_raster(box(0, 0, 1, 1), parse_nozzle("circle:d=0.2"), parse_machine("polar"),
                   settings=Settings(resolution=0.05))
    with pytest.raises(ResourceError, match="max_memory"):
        raster(box(0, 0, 100, 100), "ellipse:major=1,minor=0.4", "ttr", h=0.001,
               max_memory=64 << 20)
    with pytest.raises(InputError):
        raster(Polygon(), "circle:d=0.2")


def test_memory_refusal_for_the_per_angle_masks():
    """The grid fits but the masks of many angles do not: refused before they are allocated."""
    from printability.mmc.raster import estimate_memory

    g = CATALOGUE["hexagon"]
    settings_ = Settings(resolution=0.02, angle_step=1.0)
    prob = prepare_raster(as_region(g), parse_nozzle("ellipse:major=1,minor=0.3"),
                          parse_machine("ttr"), settings=settings_)
    grid = Grid(0.0, 0.0, 0.02, prob.grid.nx + 2, prob.grid.ny + 2)
    limit = estimate_memory(grid, len(prob.angles), prob.radius, band_words=0) + 1000
    with pytest.raises(ResourceError, match="motion restriction at 180 angles"):
        raster(g, "ellipse:major=1,minor=0.3", "ttr", h=0.02, angle_step=1.0,
               max_memory=limit)


def test_progress_bar_runs(capsys):
    res = raster(box(0, 0, 2, 1), "ellipse:major=0.6,minor=0.2", "ttr:step=45", h=0.05,
                 progress=True)
    assert res.lost_area_bounds[0] <= res.lost_area <= res.lost_area_bounds[1]


# ----------------------------------------------------------------------------- kernels


def test_conservative_classification_and_exact_coverage():
    rng = np.random.default_rng(1)
    t = np.sort(rng.uniform(0, 2 * math.pi, 50))
    rad = rng.uniform(1, 3, 50)
    g = as_region(Polygon(np.c_[rad * np.cos(t), rad * np.sin(t)],
                          [[(0.1, 0.1), (0.5, 0.1), (0.3, 0.6)]]))
    grid = Grid.covering(g.bounds, 0.11, margin=0.2)
    cls, cov = rasterize_region(g, grid)
    i, j = np.indices(grid.shape)
    boxes = shapely.box(grid.x0 + j * grid.h, grid.y0 + i * grid.h,
                        grid.x0 + (j + 1) * grid.h, grid.y0 + (i + 1) * grid.h)
    exact = shapely.area(shapely.intersection(g, boxes)) / grid.pixel_area
    np.testing.assert_allclose(cov, exact, atol=1e-9)
    assert shapely.contains(g, boxes[cls == 3]).all()
    assert not shapely.intersects(g, boxes[cls == 0]).any()
    assert (cls[shapely.intersects(g.boundary, boxes)] >= 1).all()
    assert cov.sum() * grid.pixel_area == pytest.approx(g.area, rel=1e-12)


def test_word_morphology_matches_scipy():
    from scipy import ndimage

    rng = np.random.default_rng(5)
    img = ndimage.binary_opening(rng.random((90, 200)) > 0.3, iterations=2)
    radius = 6
    kern = np.zeros((2 * radius + 1, 2 * radius + 1), bool)
    kern[3:10, 1:12] = True
    kern[radius, radius] = True
    kern[0, radius + 2] = True  # an asymmetric kernel with a stray pixel
    res = opening_pass(rk.pack_bits(img), rk.pack_bits(np.ones_like(img)), kern[None],
                       kern[None], radius, img.shape[1], store=True, tick=lambda: None)
    # erosion without reflection: P(c) = ∧_d X(c + d) is scipy's correlation with the
    # reflected structure; padding counts as False
    ref_p = ndimage.binary_erosion(np.pad(img, radius), kern[::-1, ::-1], border_value=0)
    ref_p = ref_p[radius:-radius, radius:-radius]
    ref_s = ndimage.binary_dilation(np.pad(ref_p, radius), kern)[radius:-radius, radius:-radius]
    p = res.base.copy()
    p.reshape(-1)[res.band_i * res.base.shape[1] + res.band_w] = res.values[0]
    assert np.array_equal(rk.unpack_bits(p, img.shape[1]), ref_p)
    assert np.array_equal(rk.unpack_bits(res.union, img.shape[1]), ref_s)


def test_pack_unpack_roundtrip():
    rng = np.random.default_rng(2)
    m = rng.random((7, 131)) > 0.5
    bits = rk.pack_bits(m)
    assert bits.shape == (7, 3) and bits.dtype == np.uint64
    assert np.array_equal(rk.unpack_bits(bits, 131), m)
    runs = _mask_runs(np.array([[0, 1, 1, 0, 1]], bool), 0)
    assert runs == [(0, 1, 2), (0, 4, 1)]


# ----------------------------------------------------------------------------- properties

rects = st.tuples(st.floats(0, 3), st.floats(0, 3), st.floats(0.3, 2.5), st.floats(0.3, 2.5))


def _union_of(rs):
    return as_region(shapely.union_all([box(x, y, x + w, y + h) for x, y, w, h in rs]))


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(rects, min_size=1, max_size=4), st.floats(0.2, 0.8))
def test_property_inner_as_built_inside_region(rs, d):
    g = _union_of(rs)
    if g.area < math.pi * d * d / 4:
        return
    res = raster(g, f"ellipse:major={d},minor={d / 2}", "ttr:step=30", h=0.05)
    assert res.as_built.difference(g).area == 0.0
    lo, hi = res.lost_area_bounds
    assert 0 <= lo <= res.lost_area <= hi <= res.target_area + 1e-9


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(rects, min_size=1, max_size=3), st.floats(0.2, 0.7))
def test_property_opening_is_idempotent_on_the_raster(rs, d):
    g = _union_of(rs)
    noz = parse_nozzle(f"ellipse:major={d},minor={d / 3}")
    prob = prepare_raster(g, noz, parse_machine("ttr:step=45"), settings=Settings(resolution=0.05))
    nx = prob.grid.nx
    x = rk.pack_bits(prob.cls >= 2)
    once = opening_pass(x, x, prob.centre, prob.centre, prob.radius, nx, store=False,
                        tick=lambda: None).union
    twice = opening_pass(once, once, prob.centre, prob.centre, prob.radius, nx, store=False,
                         tick=lambda: None).union
    assert np.array_equal(once, twice)


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(rects, min_size=1, max_size=3), st.floats(0.2, 0.6), st.floats(0.05, 0.4))
def test_property_bigger_circle_never_loses_less_on_xy(rs, d, extra):
    g = _union_of(rs)
    assume(g.area > math.pi * d**2 / 4)  # a nozzle larger than G is refused (tested elsewhere)
    small = raster(g, f"circle:d={d}", h=0.05)
    big = raster(g, f"circle:d={d + extra}", h=0.05) if g.area > math.pi * (d + extra) ** 2 / 4 \
        else None
    if big is None:
        return
    # λ(G \\ S) grows with the disk, so hi(big) ≥ lost(big) ≥ lost(small) ≥ lo(small)
    assert big.lost_area_bounds[1] >= small.lost_area_bounds[0]
    # the inner (certain) result loses at least as much: its touch kernels are nested
    # (P shrinks), though digital disks are not open w.r.t. each other, so S may not nest
    assert big.motion.count.data.sum() <= small.motion.count.data.sum()


def test_erode3():
    m = np.ones((5, 6), bool)
    out = _erode3(m)
    assert out[1:-1, 1:-1].all() and not out[0].any() and not out[:, -1].any()

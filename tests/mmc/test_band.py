"""The raster engine's band settling (printability.mmc._band): certified below the pixel.

What must hold: the bounds contain the exact lost area (closed forms, the exact engine's
certified interval, an independent shapely opening), the pieces it trusts lie inside G,
the kernels agree with brute force, and the bounds and estimate are tight (issue #26:
within 1 % and hi − lo ≤ 5 % of the loss or 0.05 % of the part at default settings).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, assume, example, given
from hypothesis import settings as hyp_settings
from hypothesis import strategies as st
from shapely.geometry import Polygon
from shapes import (
    catalogue,
    corner_catalogue,
    corner_form_holds,
    corner_loss,
    ellipse_opening_loss,
    rectangle,
    star,
)

from printability.mmc import _band, compute_mmc
from printability.mmc._band_geometry import poly_dist
from printability.mmc._band_lower import min_support
from printability.mmc._band_slides import blocked_interval
from printability.mmc._raster_prepare import oriented_rings, prepare_raster
from printability.mmc.raster import mmc_raster
from printability.mmc.result import MMCInternalError
from printability.model.geometry import as_region, rotation_matrix
from printability.model.machine import parse_machine
from printability.model.nozzle import parse_nozzle
from printability.settings import Settings


def raster(region, nozzle, machine="xy", h=0.05, *, settle=True, **kw):
    return mmc_raster(as_region(region), parse_nozzle(nozzle), parse_machine(machine),
                      settings=Settings(resolution=h, **kw), settle_band=settle)


def width(r):
    lo, hi = r.lost_area_bounds
    return hi - lo


# --------------------------------------------------------------------------- closed forms


CORNERS = corner_catalogue()


@pytest.mark.parametrize("d", [0.5, 1.2, 2.0])
@pytest.mark.parametrize("name", sorted(CORNERS))
def test_corner_closed_form_inside_tight_bounds(name, d):
    """A disk's corner losses: inside the bounds, estimate within 1 %, hi − lo within 5 %."""
    g = CORNERS[name].region
    assert corner_form_holds(g, d / 2)
    exact = corner_loss(g, d / 2)
    r = raster(g, f"circle:d={d}")
    lo, hi = r.lost_area_bounds
    assert lo <= exact <= hi, (lo, exact, hi)
    assert abs(r.lost_area - exact) <= 0.01 * exact + 1e-4 * g.area * 0.01
    assert hi - lo <= max(0.05 * exact, 5e-4 * g.area)
    # the plain raster is far wider: the band is what settles it
    plain = raster(g, f"circle:d={d}", settle=False)
    assert width(plain) > 5 * (hi - lo)


def test_rectangle_loses_four_minus_pi_r_squared():
    r_ = 0.4
    r = raster(rectangle(10, 4), f"circle:d={2 * r_}")
    exact = (4 - math.pi) * r_ * r_
    lo, hi = r.lost_area_bounds
    assert lo <= exact <= hi and hi - lo < 0.03 * exact
    assert r.lost_area == pytest.approx(exact, rel=2e-3)
    band = r.extra["band"]
    assert band["pieces"] > 0 and band["pixels"] > 0
    assert any("band settled" in n for n in r.notes)


# --------------------------------------------------------------------------- oracles


@pytest.mark.parametrize("name", sorted(catalogue()))
def test_bounds_overlap_the_exact_engine_ttr(name):
    """The exact engine's certified interval and the raster's must share the exact value."""
    g = catalogue()[name].region
    if name.startswith("slice:"):
        pytest.skip("the exact engine takes seconds per real slice on T-T-R (test_raster_oracles)")
    spec, machine = "ellipse:major=0.8,minor=0.3", "ttr:step=15"
    ex = compute_mmc(g, spec, machine, engine="exact")
    r = raster(g, spec, machine, h=0.04)
    elo, ehi = ex.lost_area_bounds
    lo, hi = r.lost_area_bounds
    assert lo <= ehi + 1e-9 and elo <= hi + 1e-9, (ex.lost_area_bounds, r.lost_area_bounds)
    assert lo <= r.lost_area <= hi


@pytest.mark.parametrize("name,spec,step", [
    ("star", "ellipse:major=0.9,minor=0.35", 2.0),
    ("u_shape", "ellipse:major=0.8,minor=0.3", 2.0),
    ("comb", "ellipse:major=0.6,minor=0.25", 3.0),
    ("l_shape", "ellipse:major=1.6,minor=0.6", 5.0),
])
def test_oracle_inside_bounds_and_estimate_close(name, spec, step):
    """A shapely opening at every sampled angle (and halfway between) lies in the bounds."""
    g = catalogue()[name].region
    noz = parse_nozzle(spec)
    f = noz.footprints[0]
    r = raster(g, spec, f"ttr:step={step}")
    fine, tol = ellipse_opening_loss(g, f.a, f.b, np.arange(0.0, 180.0, step / 2))
    lo, hi = r.lost_area_bounds
    assert lo - tol <= fine <= hi + tol, (lo, fine, hi, tol)
    sampled, _ = ellipse_opening_loss(g, f.a, f.b, np.arange(0.0, 180.0, step))
    assert r.lost_area == pytest.approx(sampled, rel=0.01, abs=1e-4 * g.area)


def test_issue26_star_at_defaults():
    """The issue's kind of star (sharp tips lost): 1 % and 5 % at default settings."""
    g = as_region(star(34, 10.0, 4.8))
    r = compute_mmc(g, "ellipse:major=0.9,minor=0.35", "ttr", engine="raster")
    oracle, tol = ellipse_opening_loss(g, 0.45, 0.175, np.arange(0.0, 180.0, 1.0))
    lo, hi = r.lost_area_bounds
    assert lo - tol <= oracle <= hi + tol
    assert abs(r.lost_area - oracle) <= 0.01 * oracle
    assert hi - lo <= 0.05 * oracle


# --------------------------------------------------------------------------- pieces and kernels


def _pieces(g, spec, machine, h=0.05):
    g = as_region(g)
    noz, mach = parse_nozzle(spec), parse_machine(machine)
    prob = prepare_raster(g, noz, mach, settings=Settings(resolution=h))
    f = noz.footprints[0]
    lmats = [rotation_matrix(noz.mount_angle + float(p) + f.rotation) @ np.diag([f.a, f.b])
             for p in prob.angles]
    edges, prev_, _ = _band.edges_of(*oriented_rings(g))
    ptr, idx = _band.neighbour_pairs(edges, 2.02 * max(f.a, f.b))
    return g, lmats, _band.band_pieces(g, edges, prev_, ptr, idx, lmats, prob.grid, prob.cls)


@pytest.mark.parametrize("name", ["star", "u_shape", "ring", "comb", "slot_30deg"])
def test_every_piece_lies_inside_the_part(name):
    """Quads and caps are placements' sweeps: inside G (up to their ε sliver)."""
    g, _, pieces = _pieces(catalogue()[name].region, "ellipse:major=0.8,minor=0.3", "ttr:step=10")
    grown = g.buffer(1e-6)
    quads = shapely.polygons(pieces.quads.reshape(-1, 4, 2))
    assert shapely.contains(grown, quads).all()
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    circle = np.column_stack([np.cos(t), np.sin(t)]) * (1 - 1e-6)
    for cap in pieces.caps[:: max(1, len(pieces.caps) // 300)]:
        lm = np.linalg.inv(cap[2:].reshape(2, 2))
        pts = circle @ lm.T + cap[:2]
        assert shapely.contains_xy(grown, pts[:, 0], pts[:, 1]).all()


def test_circle_pieces_lie_inside_the_exact_opening():
    """For a disk on XY every piece is part of S = opening(G, D): inside a fine shapely one."""
    g = CORNERS["arrow"].region
    r_ = 0.6
    _, _, pieces = _pieces(g, f"circle:d={2 * r_}", "xy")
    opened = g.buffer(-r_, quad_segs=256).buffer(r_, quad_segs=256).buffer(1e-4)
    quads = shapely.polygons(pieces.quads.reshape(-1, 4, 2))
    assert shapely.contains(opened, quads).all()


@given(st.floats(-3, 3), st.floats(-3, 3), st.floats(0, 2 * math.pi), st.floats(-2, 2),
       st.floats(-2, 2), st.floats(-2, 2), st.floats(-2, 2), st.floats(0.2, 2.0))
@hyp_settings(max_examples=300, deadline=None)
# a segment 3.6e-162 long: its squared length is subnormal (a CI run found it)
@example(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 3.5799398179312725e-162, 0.75)
def test_blocked_interval_matches_brute_force(p0x, p0y, ang, g0x, g0y, g1x, g1y, r):
    tx, ty = math.cos(ang), math.sin(ang)
    lo, hi = blocked_interval(p0x, p0y, tx, ty, -ty, tx, g0x, g0y, g1x, g1y, r)
    g0, g1 = np.array([g0x, g0y]), np.array([g1x, g1y])
    for s in np.linspace(-8, 8, 161):
        # the distance to the segment, bracketed by a fine sampling of it (shapely gives
        # inf for a segment shorter than 1e-200): d_hi ≥ the distance ≥ d_lo
        q = np.array([p0x + s * tx, p0y + s * ty])
        pts = g0 + np.linspace(0, 1, 4001)[:, None] * (g1 - g0)
        d_hi = float(np.min(np.hypot(*(pts - q).T)))
        d_lo = d_hi - float(np.hypot(*(g1 - g0))) / 8000
        if d_hi < r * (1 - 1e-9):
            assert lo - 1e-9 <= s <= hi + 1e-9, (s, d_hi, lo, hi)
        elif d_lo > r * (1 + 1e-9):
            assert not (lo + 1e-9 < s < hi - 1e-9), (s, d_lo, lo, hi)


@given(st.floats(0, 2 * math.pi), st.floats(0, 2 * math.pi), st.floats(0, 0.5),
       st.floats(0.1, 2), st.floats(0.1, 2))
@hyp_settings(max_examples=300, deadline=None)
def test_min_support_matches_brute_force(alpha, theta, hw, a, b):
    a, b = max(a, b), min(a, b)
    m = min_support(alpha, theta, hw, a, b)
    ts = np.linspace(theta - hw, theta + hw, 2001)
    psi = alpha - ts
    brute = np.sqrt(a * a * np.cos(psi) ** 2 + b * b * np.sin(psi) ** 2).min()
    assert m <= brute * (1 + 1e-12) and m >= brute - 1e-4 * a


@given(st.lists(st.tuples(st.floats(-3, 3), st.floats(-3, 3)), min_size=3, max_size=6),
       st.lists(st.tuples(st.floats(-3, 3), st.floats(-3, 3)), min_size=3, max_size=6))
@hyp_settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
def test_polygon_distance_matches_shapely(pts_a, pts_b):
    hulls = [shapely.MultiPoint(p).convex_hull for p in (pts_a, pts_b)]
    assume(all(isinstance(h, Polygon) and h.area > 1e-3 for h in hulls))
    xy = [np.asarray(shapely.geometry.polygon.orient(h, 1.0).exterior.coords)[:-1]
          for h in hulls]
    d = poly_dist(xy[0][:, 0].copy(), xy[0][:, 1].copy(), len(xy[0]),
                  xy[1][:, 0].copy(), xy[1][:, 1].copy(), len(xy[1]))
    assert d == pytest.approx(hulls[0].distance(hulls[1]), abs=1e-9)


# --------------------------------------------------------------------------- random shapes


@st.composite
def star_polygons(draw):
    n = draw(st.integers(3, 9))
    angles = np.sort(draw(st.lists(st.floats(0, 2 * math.pi), min_size=n, max_size=n,
                                   unique=True)))
    radii = draw(st.lists(st.floats(2.0, 8.0), min_size=n, max_size=n))
    xy = np.column_stack([radii * np.cos(angles), radii * np.sin(angles)])
    poly = Polygon(xy)
    assume(poly.is_valid and poly.area > 4.0)
    gaps = np.diff(np.append(angles, angles[0] + 2 * math.pi))
    assume(gaps.max() < math.pi * 0.95 and gaps.min() > 0.05)
    # no vertex within 0.05 mm of its neighbours' chord: GEOS buffers (the oracle's) drop
    # such "shallow" vertices, which would blur the oracle beyond its chord allowance
    prev, nxt = np.roll(xy, 1, axis=0), np.roll(xy, -1, axis=0)
    chord = nxt - prev
    rel = xy - prev
    cross = chord[:, 0] * rel[:, 1] - chord[:, 1] * rel[:, 0]
    dev = np.abs(cross) / np.maximum(np.hypot(*chord.T), 1e-12)
    assume(dev.min() > 0.05)
    return poly


@given(star_polygons(), st.sampled_from([0.4, 0.9, 1.6]), st.booleans())
@hyp_settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                     HealthCheck.filter_too_much])
def test_random_polygons_disk_xy_contains_the_exact_interval(poly, d, cw):
    """Random star-shaped polygons, a disk on XY: the bounds hold a shapely opening (within
    its chord allowance), share a value with the exact engine's certified interval, and
    contain the corner closed form when it holds."""
    g = as_region(Polygon(list(poly.exterior.coords)[::-1]) if cw else poly)
    r = raster(g, f"circle:d={d}", h=0.05)
    lo, hi = r.lost_area_bounds
    fine, tol = ellipse_opening_loss(g, d / 2, d / 2, [0.0])
    assert lo - tol <= fine <= hi + tol, (lo, fine, hi, tol)
    try:
        ex = compute_mmc(g, f"circle:d={d}", "xy", engine="exact")
    except MMCInternalError:
        ex = None  # the exact engine's own check refused this input (issue #26, open)
    if ex is not None:
        elo, ehi = ex.lost_area_bounds
        assert lo <= ehi + 1e-9 and elo <= hi + 1e-9, ((lo, hi), (elo, ehi))
    if corner_form_holds(g, d / 2):
        exact = corner_loss(g, d / 2)
        assert lo <= exact <= hi


@given(star_polygons(), st.sampled_from([(0.8, 0.3), (1.2, 0.5)]), st.floats(0, 90))
@hyp_settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                     HealthCheck.filter_too_much])
def test_random_polygons_ellipse_ttr_contain_the_oracle(poly, axes, mount):
    """Random polygons, a mounted ellipse turning on T-T-R: a shapely opening over every
    sampled angle and the angles halfway lies within the bounds (its chord allowance)."""
    g = as_region(poly)
    major, minor = axes
    spec = f"ellipse:major={major},minor={minor},angle={mount:.3f}"
    r = raster(g, spec, "ttr:step=6", h=0.05)
    lo, hi = r.lost_area_bounds
    angles = mount + np.arange(0.0, 180.0, 3.0)
    fine, tol = ellipse_opening_loss(g, major / 2, minor / 2, angles)
    assert lo - tol <= fine <= hi + tol, (lo, fine, hi, tol)

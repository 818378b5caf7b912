"""The bead union G' (printability.planning.beadunion) against GEOS.

Oracles: GEOS's union of the very same convex polygons (boundary, area,
point location), and GEOS's reconstruction of G (quad_segs 32) for the
promise G ⊕ sτ ⊆ G' ⊆ G₃₂ ⊕ τ (s = SIDE), on real slicer layers and on random beads.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from hypothesis import example, given, settings
from hypothesis import strategies as st

from gcode import parse_gcode
from printability.errors import InputError
from printability.planning.beadunion import SIDE, bead_union, union_contains_xy, union_covers
from printability.settings import Settings
from printability.sources.gcode import layer_beads

TAU = 0.95e-3  # the post-processor's default: 1 µm less the 4-decimal rounding


def _edges(u):
    return shapely.multilinestrings(
        [[(a, b), (c, d)] for a, b, c, d in zip(u.ex0, u.ey0, u.ex1, u.ey1, strict=True)])


def _without_zero_area_holes(geom):
    """GEOS's union less the holes of no area it leaves where three grown caps nearly meet
    (seen: a hole 2.8 µm round and 1.6e-19 mm² in area, its sides ~1e-16 mm apart): rounding
    artefacts, not gaps, which G' has no reason to keep."""
    polys = [shapely.Polygon(q.exterior, [h for h in q.interiors
                                          if shapely.Polygon(h).area > 1e-15])
             for q in shapely.get_parts(geom)]
    return shapely.union_all(polys) if len(polys) != 1 else polys[0]


def _check_against_geos(p0, p1, r, tau, rng):
    u = bead_union(p0, p1, r, grow=tau)
    ref = _without_zero_area_holes(u.geometry())  # GEOS union of the same polygons
    # the kept edges are on the union's boundary (within ε = 1e-9 mm), and they cover it but
    # for the gaps where two faces meet at a shallow angle θ (about 2ε/sin θ long)
    edges = _edges(u)
    ends = shapely.points(np.column_stack([np.r_[u.ex0, u.ex1, (u.ex0 + u.ex1) / 2],
                                           np.r_[u.ey0, u.ey1, (u.ey0 + u.ey1) / 2]]))
    assert shapely.distance(ends, ref.boundary).max(initial=0.0) < 1e-8
    corners = shapely.points(shapely.get_coordinates(ref.boundary))
    assert shapely.distance(corners, edges).max(initial=0.0) < 1e-5
    assert u.area == pytest.approx(ref.area, rel=2e-6, abs=1e-12)
    # GEOS may keep a seam where two polygons touch along an edge from either side (their
    # caps' edges run in the same few directions): its points are inside the union on both
    # sides, and G' keeps no edge there (the tie rule). Each seam counts twice in GEOS's
    # boundary length.
    seams = shapely.line_merge(shapely.difference(ref.boundary, edges.buffer(1e-7)))
    for part in shapely.get_parts(seams):
        (ax, ay), (bx, by) = part.coords[0], part.coords[-1]
        mx, my = part.interpolate(0.5, normalized=True).coords[0]
        nx, ny = np.array([ay - by, bx - ax]) / math.hypot(bx - ax, by - ay)
        assert shapely.contains_xy(ref, [mx + 1e-7 * nx, mx - 1e-7 * nx],
                                   [my + 1e-7 * ny, my - 1e-7 * ny]).all(), \
            f"a piece of the union's boundary is missing near ({mx}, {my})"
    assert u.perimeter == pytest.approx(ref.boundary.length - 2 * seams.length, rel=1e-6)
    x0, y0, x1, y1 = ref.bounds
    px, py = rng.uniform(x0, x1, 4000), rng.uniform(y0, y1, 4000)
    np.testing.assert_array_equal(union_contains_xy(u, px, py), shapely.intersects_xy(ref, px, py))
    # between the beads grown by sτ and the 32-segment beads grown by τ
    lines = shapely.linestrings(np.stack([p0, p1], axis=1))
    g32 = shapely.union_all(shapely.buffer(lines, r, quad_segs=32))
    g_half = shapely.union_all(shapely.buffer(lines, r + SIDE * tau * (1 - 1e-6), quad_segs=64))
    assert shapely.difference(ref, g32.buffer(tau, quad_segs=32)).area < 1e-12
    assert shapely.difference(g_half, ref).area < 1e-12
    return u


def _layers(path, n):
    g = parse_gcode(path.read_bytes())
    seg, width, _, _, bounds, _ = layer_beads(g, settings=Settings(quad_segs=32))
    out = []
    for k in np.linspace(0, len(g.layers) - 1, n).astype(int):
        rows = np.arange(bounds[k], bounds[k + 1])
        rows = rows[np.isfinite(width[rows]) & (width[rows] > 0)]
        if rows.size:
            s = seg[rows]
            out.append((np.column_stack([s["x0"], s["y0"]]), np.column_stack([s["x1"], s["y1"]]),
                        width[rows] / 2))
    return out


@pytest.mark.parametrize("fixture", ["prusa_short", "benchy_short"])
def test_real_layers_match_geos(request, fixture):
    rng = np.random.default_rng(0)
    layers = _layers(request.getfixturevalue(fixture), 3)
    assert layers
    for p0, p1, r in layers:
        _check_against_geos(p0, p1, r, TAU, rng)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 40),
       tau=st.sampled_from([0.95e-3, 0.01, 0.05]))
@example(seed=8966, n=11, tau=0.01)  # two beads touching along an edge (found by hypothesis)
@example(seed=11288, n=29, tau=0.05)  # two caps touching along an edge: a seam in GEOS's union
@example(seed=616, n=37, tau=0.05)  # three caps nearly meeting: a hole of no area in GEOS's
def test_random_beads_match_geos(seed, n, tau):
    rng = np.random.default_rng(seed)
    p0 = rng.uniform(0, 4, (n, 2)).round(3)  # slicer-like: 1 µm coordinates
    p1 = (p0 + rng.normal(0, 1.0, (n, 2))).round(3)
    p1[: n // 5] = p0[: n // 5] + np.array([0.5, 0.0])  # some parallel neighbours
    r = rng.choice([0.2, 0.225, 0.3], n)
    _check_against_geos(p0, p1, r, tau, rng)


def test_beads_that_just_touch_leave_no_edge_between_them():
    """Opposite edges lying on each other are inside the union: neither copy is kept."""
    tau = 2.0**-7
    # the polygons' straight sides, through Q's extreme corners: between r + sτ and the
    # corners' radius from the path (the same for both beads, which run the same way)
    one = bead_union(np.array([[0.0, 0.0]]), np.array([[4.0, 0.0]]), np.array([0.25]), grow=tau)
    rho = float(one.vy.max())
    assert 0.25 + SIDE * tau <= rho <= 0.25 + tau
    p0 = np.array([[0.0, 0.0], [1.0, 2 * rho]])
    p1 = np.array([[4.0, 0.0], [5.0, 2 * rho]])
    u = _check_against_geos(p0, p1, np.full(2, 0.25), tau, np.random.default_rng(2))
    mx, my = (u.ex0 + u.ex1) / 2, (u.ey0 + u.ey1) / 2
    between = (np.abs(my - rho) < 1e-6) & (mx > 1.0) & (mx < 4.0)  # where both beads are
    assert not between.any()
    assert shapely.get_num_geometries(u.geometry()) == 1


def test_a_move_printed_twice_leaves_one_boundary():
    p0 = np.array([[0.0, 0.0], [0.0, 0.0], [5.0, 0.0]])
    p1 = np.array([[5.0, 0.0], [5.0, 0.0], [5.0, 3.0]])
    u = _check_against_geos(p0, p1, np.full(3, 0.225), TAU, np.random.default_rng(1))
    once = bead_union(p0[1:], p1[1:], np.full(2, 0.225), grow=TAU)
    assert u.perimeter == pytest.approx(once.perimeter, rel=1e-12)
    assert u.area == pytest.approx(once.area, rel=1e-12)


def test_a_matched_footprint_clears_the_sides():
    """A bead's own width fits with sτ to spare; τ more does not."""
    u = bead_union(np.array([[0.0, 0.0]]), np.array([[10.0, 0.0]]), np.array([0.225]), grow=TAU)
    inside = shapely.box(1.0, -0.225, 9.0, 0.225)
    outside = shapely.box(1.0, -0.225 - TAU, 9.0, 0.225)
    assert union_covers(u, np.array([inside, outside])).tolist() == [True, False]
    # the caps: no corner further than r·cos(π/128) + τ from the segment
    corners = shapely.points(np.column_stack([u.vx, u.vy]))
    d = shapely.distance(shapely.LineString([(0, 0), (10, 0)]), corners)
    assert d.max() <= 0.225 * math.cos(math.pi / 128) + TAU + 1e-12


def test_empty_and_bad_input():
    u = bead_union(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), grow=TAU)
    assert u.is_empty and u.area == 0 and len(u.ex0) == 0
    assert not union_contains_xy(u, np.array([0.0]), np.array([0.0])).any()
    with pytest.raises(InputError, match="positive tolerance"):
        bead_union(np.zeros((1, 2)), np.ones((1, 2)), np.array([0.2]), grow=0.0)
    with pytest.raises(InputError, match="too small"):
        bead_union(np.zeros((1, 2)), np.ones((1, 2)), np.array([0.2]), grow=1e-6)
    with pytest.raises(InputError, match="positive and finite"):
        bead_union(np.zeros((1, 2)), np.ones((1, 2)), np.array([-0.2]), grow=TAU)


@pytest.mark.parametrize("nozzle", ["ellipse:major=0.8,minor=0.3",
                                    "ellipse:major=0.8,minor=0.3,x=0.3,y=-0.1"])
def test_the_fused_search_decides_as_geos_on_a_bead_union(nozzle):
    """``fits`` (fused kernel; points located in the polygons, also for an offset orifice
    whose footprint need not hold its path) against GEOS's covers on the same union."""
    from printability.model.nozzle import parse_nozzle
    from printability.planning.footprints import convex_pieces, fits

    rng = np.random.default_rng(7)
    n = 60
    p0 = rng.uniform(0, 6, (n, 2)).round(3)
    p1 = (p0 + rng.normal(0, 1.5, (n, 2))).round(3)
    u = bead_union(p0, p1, np.full(n, 0.3), grow=TAU)
    m = 3000
    q0 = rng.uniform(0, 6, (m, 2))
    q1 = q0 + rng.normal(0, 0.5, (m, 2))
    angle = rng.uniform(0, 360, m)
    pieces = convex_pieces(parse_nozzle(nozzle))
    fast = fits(u, pieces, q0, q1, angle)
    slow = fits(u, pieces, q0, q1, angle, fast=False)
    np.testing.assert_array_equal(fast, slow)
    assert fast.any() and not fast.all()


def _random_polygons(rng, n, *, lengths, radii, tau):
    """n bead polygons on random segments (lengths drawn from ``lengths``, radii uniform
    in ``radii``): the beads, their polygons and corner cosines."""
    from printability.planning._bead_boundary import _corner_cosines
    from printability.planning._bead_polygons import bead_polygons
    from printability.planning.beadunion import INNER
    from printability.planning.records import BeadPolygons, Beads, HalfPlanes

    ax, ay = rng.uniform(-5, 5, n), rng.uniform(-5, 5, n)
    length = rng.choice(lengths, n)
    ang = rng.uniform(0, 2 * math.pi, n)
    bx, by = ax + length * np.cos(ang), ay + length * np.sin(ang)
    r = rng.uniform(*radii, n)
    rho, rmax = r + SIDE * tau, r * INNER + tau
    off, ux, uy, h, vx, vy, box, k, phase = bead_polygons(ax, ay, bx, by, rho, rmax)
    return (Beads(ax, ay, bx, by, rho),
            BeadPolygons(HalfPlanes(off, ux, uy, h), vx, vy, box, k, phase), _corner_cosines(k))


@pytest.mark.parametrize("tau", [TAU, 1e-2, 0.1])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_windowed_clip_is_the_full_clip_to_the_bit(seed, tau):
    """_clip_windows skips the half-planes that hold both ends of an edge by a margin; the
    interval must be the full Liang–Barsky loop's, bit for bit, for edges at any distance
    and direction from the polygon (near its sides, its caps and far from it)."""
    from printability.planning._bead_boundary import _clip, _clip_windows, _window
    from printability.planning.beadunion import _EPS

    rng = np.random.default_rng(seed)
    n = 40
    beads, polys, vc = _random_polygons(
        rng, n, lengths=[0.0, 0.05, 1.0, 4.0], radii=(0.1, 0.6), tau=tau)
    ax, ay, bx, by, rho = beads
    off, ks = polys.planes.off, polys.k
    windowed = 0
    for j in range(n):
        k = ks[j]
        # ends scattered around the polygon, from deep inside to a few radii out
        t = rng.uniform(-0.5, 1.5, 400)
        s = rng.uniform(0, 3.5 * rho[j], 400) * np.exp(1j * rng.uniform(0, 2 * math.pi, 400))
        px = ax[j] + t * (bx[j] - ax[j]) + s.real
        py = ay[j] + t * (by[j] - ay[j]) + s.imag
        e = rng.uniform(0.001, 2 * rho[j], 400) * np.exp(1j * rng.uniform(0, 2 * math.pi, 400))
        for i in range(400):
            edge = (px[i], py[i], px[i] + e[i].real, py[i] + e[i].imag)
            args = (edge, polys.planes, off[j], off[j + 1],
                    (_EPS if i % 2 else -_EPS, _EPS, math.cos(i), math.sin(i)))
            ends = [_window(x, y, beads, polys, j, _EPS, vc[k])
                    for x, y in (edge[:2], edge[2:])]
            near = _clip_windows(*args, *ends)
            assert near == _clip(*args)  # (an empty interval is (1, 0) in both)
            windowed += max(ends[0][1], ends[1][1]) < k // 2
    # most edges here take the windowed path (the test would be vacuous otherwise)
    assert windowed > n * 400 // 3


@pytest.mark.parametrize("seed", [0, 1])
def test_windows_evaluated_as_one_arc_or_two_give_the_full_clip(seed):
    """_clip_windows may take any windows that hold the planes the ends need: widened
    windows, windows far apart or wrapping past plane 0, evaluated as one arc or two, give
    the full loop's interval to the bit."""
    from printability.planning._bead_boundary import _clip, _clip_windows, _window
    from printability.planning.beadunion import _EPS

    rng = np.random.default_rng(seed)
    n = 30
    beads, polys, vc = _random_polygons(
        rng, n, lengths=[0.0, 0.3, 2.0], radii=(0.15, 0.5), tau=TAU)
    ax, ay, bx, by, rho = beads
    off, ks = polys.planes.off, polys.k
    arcs = 0
    for j in range(n):
        k = ks[j]
        for i in range(300):
            t = rng.uniform(-0.3, 1.3)
            s = rng.uniform(0.8, 1.6) * rho[j] * np.exp(1j * rng.uniform(0, 2 * math.pi))
            px = ax[j] + t * (bx[j] - ax[j]) + s.real
            py = ay[j] + t * (by[j] - ay[j]) + s.imag
            e = rng.uniform(0.001, rho[j]) * np.exp(1j * rng.uniform(0, 2 * math.pi))
            qx, qy = px + e.real, py + e.imag
            args = ((px, py, qx, qy), polys.planes, off[j], off[j + 1],
                    (_EPS if i % 2 else -_EPS, _EPS, math.cos(i), math.sin(i)))
            w = [_window(x, y, beads, polys, j, _EPS, vc[k]) for x, y in ((px, py), (qx, qy))]
            full = _clip(*args)
            assert _clip_windows(*args, *w) == full
            if max(w[0][1], w[1][1]) < k // 2:
                # a window's centre moved round by whole turns, and widened by one plane
                (j1, w1), (j2, w2) = w
                wide = [(j1 + 2 * k * rng.integers(-2, 3), min(w1 + 1, k // 2 - 1) if w1 >= 0
                         else w1), (j2 - 2 * k, w2)]
                assert _clip_windows(*args, *wide) == full
                arcs += min(w1, w2) >= 0
    assert arcs > n * 300 // 4  # both ends windowed: the one-arc path is exercised

@pytest.mark.parametrize("workers", [2, 3])
def test_threads_build_the_same_union_to_the_bit(shared_data, workers, monkeypatch):
    """The boundary pieces of a busy layer computed on threads are the single thread's, in
    the same order, and so is the area."""
    import printability.base.parallel as par

    g = parse_gcode((shared_data / "gcode" / "prusaslicer_2.7.4_marlin2_arcs.gcode").read_bytes())
    seg, width, _, _, bounds, _ = layer_beads(g, settings=Settings(quad_segs=32),
                                              filament_diameter=1.75)
    # layers side by side, 300 mm apart, as the post-processor's batches lay them
    p0, p1, r = [], [], []
    for k in range(len(g.layers)):
        rows = np.arange(bounds[k], bounds[k + 1])
        rows = rows[np.isfinite(width[rows]) & (width[rows] > 0)]
        s = seg[rows]
        p0.append(np.column_stack([s["x0"] + 300 * k, s["y0"]]))
        p1.append(np.column_stack([s["x1"] + 300 * k, s["y1"]]))
        r.append(width[rows] / 2)
        if sum(map(len, r)) >= 2 * workers * 1000:  # enough beads for a thread each
            break
    p0, p1, r = np.vstack(p0), np.vstack(p1), np.concatenate(r)
    assert len(r) >= 2 * workers * 1000
    one = bead_union(p0, p1, r, grow=TAU)
    started = []
    monkeypatch.setattr(par.threading.Thread, "start",
                        lambda self, _s=par.threading.Thread.start: (started.append(1), _s(self)))
    many = bead_union(p0, p1, r, grow=TAU, workers=workers)
    assert len(started) == workers - 1
    for name in ("ex0", "ey0", "ex1", "ey1"):
        assert np.array_equal(getattr(one, name), getattr(many, name))
    assert one.area == many.area and one.perimeter == many.perimeter

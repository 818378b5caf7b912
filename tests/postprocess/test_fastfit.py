"""The fast footprint test decides exactly as ``shapely.covers`` (differential tests).

:func:`printability.planning.fastfit.covers_rings` may only save time: every
footprint it decides must get the answer ``shapely.covers`` gives, on real
slicer files (every call the orientation search makes, move by move) and on
random targets with holes, including footprints that touch ∂G exactly.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

import printability.planning.footprints as footprints
from printability.model.nozzle import parse_nozzle
from printability.planning.fastfit import covers, covers_rings
from printability.planning.footprints import _swept, convex_pieces, grown_target
from printability.postprocess import PostprocessOptions, postprocess_bytes

NOZZLES = ["ellipse:major=0.8,minor=0.3", "rect:w=0.7,h=0.25"]


def _reference(target, rings, cu, su, h):
    # GEOS's covers, on the layer's bead union where the post-processor builds one
    return covers(target, shapely.polygons(rings))


@pytest.mark.parametrize("nozzle", NOZZLES)
@pytest.mark.parametrize("fixture", ["prusa_short", "benchy_short"])
def test_fast_and_shapely_agree_move_by_move_on_real_files(request, monkeypatch, fixture, nozzle):
    data = request.getfixturevalue(fixture).read_bytes()
    opts = PostprocessOptions(nozzle=nozzle, machine="ttr")
    calls = {"n": 0, "moves": 0, "fit": 0}
    first_fit = footprints._first_fit

    def checked(target, pieces, segments, seg, angle, gpos, gend, *, angle_end=None,
                gseg=None, trig=None, **kw):
        # every candidate the fused search tried gets shapely's answer: the ones before
        # its pick do not fit, the pick does
        first = first_fit(target, pieces, segments, seg, angle, gpos, gend,
                          angle_end=angle_end, gseg=gseg, trig=trig, **kw)
        p0, p1, scale = segments
        tried = [np.arange(lo, hi if f < 0 else f + 1)
                 for lo, hi, f in zip(gpos.tolist(), gend.tolist(), first.tolist(), strict=True)]
        q = np.concatenate(tried) if tried else np.zeros(0, dtype=np.int64)
        g = np.repeat(np.arange(len(tried)), [t.size for t in tried])
        m = np.asarray(gseg)[g] if gseg is not None else np.asarray(seg)[q]
        ref = footprints._fits_rings(
            target, pieces, p0[m], p1[m], np.asarray(angle)[q],
            angle_end=None if angle_end is None else np.asarray(angle_end)[q],
            scale=None if scale is None else np.asarray(scale)[m], fast=False)
        np.testing.assert_array_equal(ref, q == np.asarray(first)[g],
                                      err_msg="fused test disagrees with shapely.covers")
        calls["n"] += 1
        calls["moves"] += len(q)
        calls["fit"] += int(ref.sum())
        return first

    monkeypatch.setattr(footprints, "_first_fit", checked)
    new_fast, res_fast = postprocess_bytes(data, options=opts)
    # both answers occur: the test is not vacuous
    assert calls["fit"] > 0 and calls["moves"] - calls["fit"] > 0
    # the reference: every candidate of every round through shapely.covers (the search
    # before the fused kernel), which must plan the same
    monkeypatch.setattr(footprints, "_fused", lambda pieces: False)
    monkeypatch.setattr(footprints, "covers_rings", _reference)
    new_slow, res_slow = postprocess_bytes(data, options=opts)
    assert new_fast == new_slow
    assert (res_fast.split_moves, res_fast.dropped_moves) == \
        (res_slow.split_moves, res_slow.dropped_moves)


def _random_target(rng):
    outer = shapely.Polygon(rng.uniform(-5, 5, (12, 2))).convex_hull.buffer(0.5)
    holes = [shapely.Point(rng.uniform(-3, 3, 2)).buffer(rng.uniform(0.2, 1.0), quad_segs=3)
             for _ in range(3)]
    box = shapely.box(-1.0, -1.0, 1.0, 1.0)  # straight edges a footprint can lie on exactly
    return shapely.union_all([outer.difference(shapely.union_all(holes)), box])


@pytest.mark.parametrize("nozzle", NOZZLES)
@pytest.mark.parametrize("seed", range(4))
def test_fast_and_shapely_agree_on_random_targets(nozzle, seed):
    rng = np.random.default_rng(seed)
    target = grown_target(_random_target(rng), 0.0)
    n = 4000
    p0 = rng.uniform(-5, 5, (n, 2))
    p1 = p0 + rng.normal(0, 1.0, (n, 2)) * rng.uniform(0, 1, (n, 1))
    p1[:50] = p0[:50]  # standing still
    angle = rng.uniform(0, 360, n)
    for piece in convex_pieces(parse_nozzle(nozzle)):
        rings, cu, su, h = _swept(piece, p0, p1, angle)
        fast = covers_rings(target, rings, cu, su, h)
        slow = _reference(target, rings, cu, su, h)
        np.testing.assert_array_equal(fast, slow)
        assert fast.any() and not fast.all()


def test_footprints_touching_the_boundary_exactly():
    """Rectangles flush with a box's sides (to rounding) or 1e-7 mm out: as shapely decides."""
    target = grown_target(shapely.box(0.0, 0.0, 10.0, 1.0), 0.0)
    piece = convex_pieces(parse_nozzle("rect:w=1.0,h=0.5"))[0]
    x = np.linspace(0.5, 9.5, 7)
    p0 = np.column_stack([x, np.full(7, 0.5)])
    covered = []
    for dy, dx in ((0.0, 0.0), (0.25, 0.0), (0.25, 0.3), (0.2500001, 0.0), (0.25, 9.0)):
        q0 = p0 + np.array([0.0, dy])
        q1 = q0 + np.array([dx, 0.0])
        rings, cu, su, h = _swept(piece, q0, q1, np.zeros(7))
        fast = covers_rings(target, rings, cu, su, h)
        np.testing.assert_array_equal(fast, _reference(target, rings, cu, su, h))
        covered.append(fast)
    assert covered[0][1:-1].all() and not covered[3].any()


@pytest.mark.parametrize("nozzle", [*NOZZLES, "circle:d=0.4",
                                    "ellipse:major=0.8,minor=0.3,rot=30,x=0.1"])
def test_swept_kernel_is_the_numpy_path_to_the_bit(nozzle):
    """The fused ring kernel repeats numpy's arithmetic: same rings, same half-planes."""
    rng = np.random.default_rng(3)
    n = 500
    p0 = rng.uniform(0, 200, (n, 2))
    p1 = p0 + rng.normal(0, 2, (n, 2))
    p1[:10] = p0[:10]
    angle = rng.uniform(-400, 400, n)
    end = angle + rng.uniform(-20, 20, n)
    scale = rng.uniform(0.3, 1.0, n)
    for piece in convex_pieces(parse_nozzle(nozzle)):
        for kw in ({}, {"angle_end": end}, {"scale": scale}, {"angle_end": end, "scale": scale}):
            fast = _swept(piece, p0, p1, angle, **kw)
            slow = _swept(piece, p0, p1, angle, kernel=False, **kw)
            for x, y in zip(fast, slow, strict=True):
                np.testing.assert_array_equal(x, y)



def test_move_normals_are_the_left_unit_normals():
    """The footprints' directions turn with the move's left normal, (1, 0) for a move of no
    length: two of the 64 half-planes are then the long sides of the swept set."""
    from printability.planning.footprints import _move_normals

    p0 = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, -1.0], [5.0, 5.0]])
    p1 = np.array([[3.0, 0.0], [1.0, 4.0], [-1.0, 3.0], [5.0, 5.0]])
    cn, sn = _move_normals(p0, p1)
    np.testing.assert_allclose(np.column_stack([cn, sn]),
                               [[0.0, 1.0], [-1.0, 0.0], [-0.8, -0.6], [1.0, 0.0]], atol=1e-15)
    rng = np.random.default_rng(5)
    q0 = rng.uniform(-100, 100, (1000, 2))
    q1 = q0 + rng.normal(0, 3, (1000, 2))
    cn, sn = _move_normals(q0, q1)
    d = q1 - q0
    np.testing.assert_allclose(np.hypot(cn, sn), 1.0, rtol=1e-15)
    np.testing.assert_allclose(cn * d[:, 0] + sn * d[:, 1], 0.0, atol=1e-12)  # normal
    assert np.all(cn * d[:, 1] - sn * d[:, 0] < 0)  # to the left of the move


def test_the_kernel_normal_is_the_numpy_normal_to_the_bit():
    """The fused kernel finds each move's normal itself (:func:`move_normal`); the rings of
    the grazing footprints take them from :func:`_move_normals`: the half-planes of both
    must be the same bits, zero-length and slicer-rounded moves included."""
    from printability.planning._sweep import move_normal
    from printability.planning.footprints import _move_normals

    rng = np.random.default_rng(11)
    q0 = rng.uniform(-300, 300, (20000, 2))
    q1 = q0 + rng.normal(0, 3, (20000, 2)) * rng.choice([0.0, 1e-6, 1.0], (20000, 1))
    q0[::7] = q0[::7].round(3)
    q1[::7] = q1[::7].round(3)
    cn, sn = _move_normals(q0, q1)
    mine = np.array([move_normal(a, b, c, d) for (a, b), (c, d) in zip(q0, q1, strict=True)])
    assert np.array_equal(mine[:, 0], cn) and np.array_equal(mine[:, 1], sn)
    assert (mine[(q0 == q1).all(axis=1)] == [1.0, 0.0]).all()


def test_chain_nearest_is_the_python_loop():
    """The compiled chaining picks what the Python loop picked, ties and halves included."""
    from printability.planning._plan_kernels import chain_nearest

    rng = np.random.default_rng(5)
    c1 = np.concatenate([rng.uniform(-720, 720, 3000), np.arange(-450.0, 450.0, 45.0)])
    c2 = np.concatenate([c1[:3000] + rng.choice([0.0, 90.0, 45.5], 3000),
                         np.arange(-450.0, 450.0, 45.0) + 90.0])
    for per in (180.0, 360.0):
        out, prev = [], 0.0
        for a, b in zip(c1.tolist(), c2.tolist(), strict=True):
            best = None
            for c in (a, b, a + 180.0, b + 180.0):
                near = c + per * round((prev - c) / per)
                if best is None or abs(near - prev) < abs(best - prev):
                    best = near
            out.append(best)
            prev = best
        np.testing.assert_array_equal(chain_nearest(c1, c2, per, 0.0), np.array(out))


@pytest.mark.parametrize("nozzle", [*NOZZLES, "ellipse:major=0.8,minor=0.3,rot=30,x=0.1"])
@pytest.mark.parametrize("seed", range(3))
def test_fused_fits_is_shapely_on_random_targets(nozzle, seed):
    """fits' fused kernel (half-planes, edge test and point location in one pass) decides
    each footprint as shapely.covers does: plain, turning and scaled, in and out of holes."""
    rng = np.random.default_rng(10 + seed)
    target = grown_target(_random_target(rng), 0.0)
    n = 3000
    p0 = rng.uniform(-6, 6, (n, 2))
    p1 = p0 + rng.normal(0, 1.0, (n, 2)) * rng.uniform(0, 1, (n, 1))
    p1[:50] = p0[:50]
    angle = rng.uniform(-400, 400, n)
    end = angle + rng.uniform(-20, 20, n)
    scale = rng.uniform(0.3, 1.0, n)
    pieces = convex_pieces(parse_nozzle(nozzle))
    for kw in ({}, {"angle_end": end}, {"scale": scale}):
        fast = footprints.fits(target, pieces, p0, p1, angle, **kw)
        slow = footprints.fits(target, pieces, p0, p1, angle, fast=False, **kw)
        np.testing.assert_array_equal(fast, slow)
        assert fast.any() and not fast.all()


def test_point_location_along_a_grid_row():
    """Footprints wholly inside a hole or wholly inside G, far from and near to ∂G, on
    rows through vertices: located as shapely locates them."""
    outer = shapely.box(0.0, 0.0, 30.0, 3.0)
    holes = [shapely.box(x, 1.0, x + 1.5, 2.0) for x in (2.0, 7.0, 12.5, 20.0)]
    target = grown_target(outer.difference(shapely.union_all(holes)), 0.0)
    pieces = convex_pieces(parse_nozzle("ellipse:major=0.4,minor=0.2"))
    x = np.linspace(0.3, 29.7, 400)
    for y in (0.5, 1.0, 1.5, 2.0, 2.5):
        p0 = np.column_stack([x, np.full(x.size, y)])
        for dx in (0.0, 0.05):
            p1 = p0 + np.array([dx, 0.0])
            angle = np.full(x.size, 90.0)
            fast = footprints.fits(target, pieces, p0, p1, angle)
            slow = footprints.fits(target, pieces, p0, p1, angle, fast=False)
            np.testing.assert_array_equal(fast, slow)


def test_smooth_chain_is_the_python_loop():
    """The compiled smoothing proposals are those of the Python loop, halves included."""
    from printability.planning._plan_kernels import smooth_chain

    rng = np.random.default_rng(6)
    n = 4000
    angle = rng.uniform(-720, 720, n)
    angle[rng.random(n) < 0.1] = np.nan
    angle[:40] = np.arange(-450.0, 450.0, 22.5)[:40]
    c1 = rng.uniform(-720, 720, n)
    c2 = c1 + rng.choice([0.0, 90.0, 45.5], n)
    searched = rng.random(n) < 0.3
    for per, reach in ((180.0, False), (360.0, False), (180.0, True)):
        prop, prev = angle.copy(), 0.0
        for i in range(n):
            a = float(angle[i])
            if a != a:
                continue
            if searched[i] or reach:
                best = a + per * round((prev - a) / per)
            else:
                best = None
                for c in (float(c1[i]), float(c2[i])):
                    near = c + per * round((prev - c) / per)
                    if best is None or abs(near - prev) < abs(best - prev):
                        best = near
            prop[i] = best
            prev = best
        np.testing.assert_array_equal(smooth_chain(angle, c1, c2, searched, reach, per, 0.0),
                                      prop)


@pytest.mark.parametrize("nozzle", [*NOZZLES, "ellipse:major=0.8,minor=0.3,rot=30,x=0.1"])
@pytest.mark.parametrize("seed", range(2))
def test_first_fit_of_groups_is_shapely_on_random_targets(nozzle, seed):
    """Many candidates per move, tried in order (the edges that refused the last
    footprints tried first, against the swept ellipses, then the half-planes; the move's
    start located once): the first that fits is the one shapely.covers finds, candidate
    by candidate, plain and scaled."""
    rng = np.random.default_rng(30 + seed)
    target = grown_target(_random_target(rng), 0.0)
    n, per = 400, 18
    p0 = rng.uniform(-6, 6, (n, 2))
    p1 = p0 + rng.normal(0, 1.0, (n, 2)) * rng.uniform(0, 1, (n, 1))
    seg = np.repeat(np.arange(n), per)
    angle = rng.uniform(-400, 400, n * per)
    gpos = np.arange(n) * per
    pieces = convex_pieces(parse_nozzle(nozzle))
    for scale in (None, rng.uniform(0.3, 1.0, n)):
        fast = footprints._first_fit(target, pieces, (p0, p1, scale), seg, angle, gpos,
                                      gpos + per)
        slow = footprints._first_fit_reference(target, pieces, p0, p1, scale, seg, angle, gpos,
                                                gpos + per)
        np.testing.assert_array_equal(fast, slow)
        assert (fast >= 0).any() and (fast < 0).any()


def test_merge_pieces_is_the_python_loop():
    """Pieces sorted by move and start and joined where adjacent (math.isclose) at the
    same orientation, as the loop over lists of tuples joined them."""
    import math

    from printability.planning._plan_kernels import merge_pieces

    rng = np.random.default_rng(5)
    n = 3000
    move = rng.integers(0, 40, n)
    t0 = np.round(rng.uniform(0, 1, n), 2)
    t1 = t0 + rng.choice([0.01, 0.02], n)
    t0[::7] = t0[::7] * (1 + 1e-12)  # within math.isclose of an end, not equal
    angle = rng.choice([0.0, 10.0, 10.0 + 1e-10, 20.0], n)
    expect = []
    for m in range(40):
        run: list[list[float]] = []
        for a, b, p in sorted(((a, b, p) for mm, a, b, p in
                               zip(move.tolist(), t0.tolist(), t1.tolist(), angle.tolist(),
                                   strict=True)
                               if mm == m), key=lambda x: x[0]):
            if run and math.isclose(run[-1][1], a) and math.isclose(run[-1][2], p):
                run[-1][1] = b
            else:
                run.append([a, b, p])
        expect += [(m, a, b, p) for a, b, p in run]
    got = list(zip(*(v.tolist() for v in merge_pieces(move, t0, t1, angle)), strict=True))
    assert got == expect
    assert len(got) < n


@pytest.mark.parametrize("nozzle", [*NOZZLES, "ellipse:major=0.8,minor=0.3,rot=30,x=0.1"])
def test_deep_in_sweep_only_where_the_edge_enters_the_footprint(nozzle):
    """The refusal shortcut of the remembered edges: where it says an edge has a piece
    deep in the swept ellipse, the footprint's polygon shrunk by far more than EPS holds
    a piece of that edge; and it says so for most edges crossing the move."""
    from printability.planning._sweep import _deep_in_sweep

    rng = np.random.default_rng(3)
    (piece,) = convex_pieces(parse_nozzle(nozzle))
    params = footprints._piece_params(piece)
    kind = params[0]
    n = 2000
    p0 = rng.uniform(-1, 1, (n, 2))
    p1 = p0 + rng.normal(0, 0.5, (n, 2))
    angle = rng.uniform(-200, 200, n)
    scale = rng.uniform(0.3, 1.0, n)
    e0 = rng.uniform(-1.5, 1.5, (n, 2))
    e1 = e0 + rng.normal(0, 0.3, (n, 2))
    rings = footprints.swept_rings(piece, p0, p1, angle, scale=scale)
    deep = 0
    for i in range(n):
        c, s = math.cos(math.radians(angle[i])), math.sin(math.radians(angle[i]))
        d = _deep_in_sweep(e0[i] - p0[i], e1[i] - p0[i], p1[i] - p0[i], params, c, s, scale[i])
        inner = shapely.Polygon(rings[i]).buffer(-1e-7)
        edge = shapely.LineString([e0[i], e1[i]])
        if d:
            deep += 1
            assert inner.intersection(edge).length > 1e-8, i
        elif not inner.buffer(-0.01).intersection(edge).is_empty and kind == 0:
            raise AssertionError(f"edge {i} deep in the ellipse swept, not found")
    assert deep > n // 20

"""The fast footprint test decides exactly as ``shapely.covers`` (differential tests).

:func:`printability.motion.fastfit.covers_rings` may only save time: every
footprint it decides must get the answer ``shapely.covers`` gives, on real
slicer files (every call the orientation search makes, move by move) and on
random targets with holes, including footprints that touch ∂G exactly.
"""

from __future__ import annotations

import numpy as np
import pytest
import shapely

import printability.motion.orientation as orientation
from printability.motion.fastfit import covers_rings
from printability.motion.orientation import _swept, convex_pieces, grown_target
from printability.nozzle import parse_nozzle
from printability.postprocess import PostprocessOptions, postprocess_bytes

NOZZLES = ["ellipse:major=0.8,minor=0.3", "rect:w=0.7,h=0.25"]


def _reference(target, rings, cu, su, h):
    return shapely.covers(target, shapely.polygons(rings))


@pytest.mark.parametrize("nozzle", NOZZLES)
@pytest.mark.parametrize("fixture", ["prusa_short", "benchy_short"])
def test_fast_and_shapely_agree_move_by_move_on_real_files(request, monkeypatch, fixture, nozzle):
    data = request.getfixturevalue(fixture).read_bytes()
    opts = PostprocessOptions(nozzle=nozzle, machine="ttr")
    calls = {"n": 0, "moves": 0, "fit": 0}

    def checked(target, rings, cu, su, h):
        fast = covers_rings(target, rings, cu, su, h)
        slow = _reference(target, rings, cu, su, h)
        bad = np.flatnonzero(fast != slow)
        assert bad.size == 0, f"fast path disagrees with shapely.covers on moves {bad[:10]}"
        calls["n"] += 1
        calls["moves"] += len(fast)
        calls["fit"] += int(fast.sum())
        return fast

    monkeypatch.setattr(orientation, "covers_rings", checked)
    new_fast, res_fast = postprocess_bytes(data, options=opts)
    # both answers occur: the test is not vacuous
    assert calls["fit"] > 0 and calls["moves"] - calls["fit"] > 0
    monkeypatch.setattr(orientation, "covers_rings", _reference)
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


def test_chain_nearest_is_the_python_loop():
    """The compiled chaining picks what the Python loop picked, ties and halves included."""
    from printability.motion.fastfit import chain_nearest

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

"""Layers side by side (printability.planning.tiles) and the post-processor planning in batches."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import printability.planning.targets as pp_targets
from printability.errors import InputError
from printability.planning.tiles import tile_layers
from printability.postprocess import PostprocessOptions, postprocess_bytes

ELLIPSE = "ellipse:major=0.8,minor=0.3"


@st.composite
def layer_boxes(draw):
    n = draw(st.integers(1, 40))
    lo = np.array(draw(st.lists(st.tuples(st.floats(-500, 500), st.floats(-500, 500)),
                                min_size=n, max_size=n)))
    size = np.array(draw(st.lists(st.tuples(st.floats(0, 80), st.floats(0, 80)),
                                  min_size=n, max_size=n)))
    weight = np.array(draw(st.lists(st.integers(0, 500), min_size=n, max_size=n)), float)
    return lo, lo + size, weight


@given(layer_boxes(), st.floats(0.1, 5), st.floats(100, 50_000), st.floats(100, 3000))
@settings(max_examples=150, deadline=None)
def test_tiles_are_disjoint_bounded_and_found_again(boxes, gap, max_area, max_weight):
    lo, hi, weight = boxes
    t = tile_layers(lo, hi, weight, gap=gap, max_area=max_area, max_weight=max_weight)
    assert t.bounds[0] == 0 and t.bounds[-1] == len(lo)
    assert np.all(np.diff(t.bounds) >= 1)
    for b in range(t.batches):
        first, stop = t.bounds[b], t.bounds[b + 1]
        n = stop - first
        px, py = t.pitch[b]
        # a batch of several layers keeps within both caps
        if n > 1:
            assert n * px * py <= max_area * (1 + 1e-9)
            assert weight[first:stop].sum() <= max_weight
        cols = t.cols[b]
        for j in range(n):
            k = first + j
            a, z = lo[k] + t.offset[k], hi[k] + t.offset[k]
            col, row = j % cols, j // cols
            # inside its own tile, at least gap/2 from its edges: boxes of a batch never meet
            assert a[0] >= col * px + gap / 2 - 1e-9 and z[0] <= (col + 1) * px - gap / 2 + 1e-9
            assert a[1] >= row * py + gap / 2 - 1e-9 and z[1] <= (row + 1) * py - gap / 2 + 1e-9
            centre = (a + z) / 2
            assert t.tile_of(b, np.array([centre[0]]), np.array([centre[1]]))[0] == j
        # outside every tile
        assert t.tile_of(b, np.array([-1.0]), np.array([0.5]))[0] == -1


def test_tile_layers_refuses_bad_input():
    lo = np.zeros((2, 2))
    hi = np.ones((2, 2))
    with pytest.raises(InputError, match="gap"):
        tile_layers(lo, hi, [1, 1], gap=0.0, max_area=10, max_weight=10)
    with pytest.raises(InputError, match="one row per layer"):
        tile_layers(lo, hi, [1], gap=1.0, max_area=10, max_weight=10)
    with pytest.raises(InputError, match="finite, non-empty box"):
        tile_layers(lo, hi - 2, [1, 1], gap=1.0, max_area=10, max_weight=10)
    empty = tile_layers(np.zeros((0, 2)), np.zeros((0, 2)), [], gap=1.0, max_area=10,
                        max_weight=10)
    assert empty.batches == 0


def test_planning_in_batches_decides_as_layer_by_layer(prusa_short, monkeypatch):
    """One union for all layers (one batch here) against one batch per layer: the same
    layers, targets and moves; the decisions may differ only where a footprint grazes
    the target within the translation's rounding (a few pieces)."""
    data = prusa_short.read_bytes()
    opts = PostprocessOptions(nozzle=ELLIPSE, machine="ttr", interior=False)
    _, batched = postprocess_bytes(data, options=opts)
    monkeypatch.setattr(pp_targets, "_BATCH_AREA", 1.0)  # every layer a batch of its own
    _, alone = postprocess_bytes(data, options=opts)
    assert [r.index for r in batched.layers] == [r.index for r in alone.layers]
    assert len(batched.layers) > 1
    for a, b in zip(batched.layers, alone.layers, strict=True):
        assert a.moves == b.moves
        assert a.target_area == pytest.approx(b.target_area, rel=1e-9)
    assert abs(batched.split_moves - alone.split_moves) <= 0.01 * alone.split_moves + 1
    assert batched.dropped_length == pytest.approx(alone.dropped_length, rel=0.02, abs=0.05)


@pytest.mark.parametrize("workers", [1, 2, 3])
def test_targets_are_built_a_bounded_number_ahead(workers):
    """The threads building layer targets run at most workers + 1 ahead of the planner:
    memory holds that many targets, not the whole part's."""
    import threading
    import time

    started = []
    lock = threading.Lock()

    def build(i):
        with lock:
            started.append(i)
        time.sleep(0.002)
        return i

    out = []
    for value in pp_targets.threaded(build, list(range(40)), workers):
        with lock:
            assert len(started) - len(out) <= workers + 1
        out.append(value)
        time.sleep(0.004)  # a slow consumer: the builders would run far ahead
    assert out == list(range(40))


@pytest.mark.parametrize("spec", ["ellipse:major=0.8,minor=0.3,x=0.6",
                                  "ellipse:major=0.6,minor=0.25,x=-0.5+rect:w=0.5,h=0.2,x=0.5"])
def test_batches_keep_offset_orifices_inside_their_layer(prusa_short, spec, monkeypatch):
    """Orifices away from the rotation axis reach farther from the path than a centred
    one: the tiles hold that reach, so a batch never lets a footprint lean on another
    layer's target, even with tiles almost touching. Swept along the emitted moves,
    nothing leaves its own layer's G."""
    from pp_helpers import geos_targets

    from gcode import parse_gcode
    from printability.model.nozzle import parse_nozzle
    from printability.planning.check import check_deposition, extrusion_chords

    monkeypatch.setattr(pp_targets, "_TILE_GAP", 1e-3)
    data = prusa_short.read_bytes()
    new, res = postprocess_bytes(data, options=PostprocessOptions(nozzle=spec, machine="ttr",
                                                                  interior=False))
    assert len(res.layers) > 1
    targets = geos_targets(parse_gcode(data), interior=False)
    layers = [i for i, t in enumerate(targets) if t is not None][1:3]
    reports = check_deposition(extrusion_chords(parse_gcode(new)), targets, parse_nozzle(spec),
                               layers=layers)
    assert len(reports) == len(layers)
    for r in reports:
        assert r.max_outside <= 1e-3 + 2e-4, f"layer {r.layer}: {r.max_outside} mm outside"


def _square_layers(n_layers: int, *, first_differs: bool) -> bytes:
    """A PrusaSlicer-like file: per layer two square loops (10 mm, 0.45 mm beads) and a
    zig-zag of infill; the first layer's infill runs the other way when ``first_differs``,
    the others repeat each other to the bit."""
    out = ["; generated by PrusaSlicer 2.7.4", "G21", "G90", "M83"]
    e = 0.45 * 0.2 / (3.14159265 * 1.75**2 / 4)  # mm of filament per mm of bead
    for k in range(n_layers):
        z = 0.2 * (k + 1)
        out += [";LAYER_CHANGE", f";Z:{z:.1f}", ";HEIGHT:0.2", f"G1 Z{z:.1f} F720"]
        for inset, kind in ((0.0, "External perimeter"), (0.45, "Perimeter")):
            a, b = 100 + inset, 110 - inset
            out += [f"G1 X{a:.3f} Y{a:.3f} F9000", f";TYPE:{kind}", ";WIDTH:0.45"]
            for x, y in ((b, a), (b, b), (a, b), (a, a)):
                out.append(f"G1 X{x:.3f} Y{y:.3f} E{e * (b - a):.5f} F1800")
        out += [";TYPE:Solid infill", ";WIDTH:0.45", "G1 X100.900 Y100.900 F9000"]
        across = k == 0 and first_differs
        for i in range(18):
            u = 100.9 + 0.45 * i
            pts = ((u, 109.1), (u + 0.45, 109.1)) if i % 2 == 0 else ((u, 100.9), (u + 0.45, 100.9))
            for x, y in pts:
                if across:
                    x, y = y, x
                out.append(f"G1 X{x:.3f} Y{y:.3f} E{e * 8.2:.5f}")
    return ("\n".join(out) + "\n").encode()


@pytest.fixture()
def union_sizes(monkeypatch):
    """The bead count of every bead union the post-processor builds, in order."""
    seen = []
    real = pp_targets.bead_union

    def spy(p0, p1, r, **kw):
        seen.append(len(p0))
        return real(p0, p1, r, **kw)

    monkeypatch.setattr(pp_targets, "bead_union", spy)
    return seen


def test_repeated_layers_share_their_twin_target(union_sizes):
    """Layers repeating an earlier one of their batch (the same beads and moves to the bit)
    are planned on its tile: their union is built once, with the same area, and what
    they print stays inside their own layer's target."""
    from pp_helpers import geos_targets

    from gcode import parse_gcode
    from printability.model.nozzle import parse_nozzle
    from printability.planning.check import check_deposition, extrusion_chords

    data = _square_layers(5, first_differs=True)
    new, res = postprocess_bytes(data, options=PostprocessOptions(nozzle=ELLIPSE, machine="ttr",
                                                                  interior=False))
    per_layer = [r.moves for r in res.layers]
    assert len(per_layer) == 5 and len(union_sizes) == 1
    assert union_sizes[0] == per_layer[0] + per_layer[1]  # layers 3 to 5 add no bead
    assert len({r.target_area for r in res.layers[1:]}) == 1
    # the first layer mirrors the others' infill: the same area to the estimate's precision
    # (the bead polygons' corners keep one orientation, so mirror images differ by ~1e-6;
    # the estimate is within 1e-5 of GEOS's G on sliced parts)
    assert res.layers[0].target_area == pytest.approx(res.layers[1].target_area, rel=1e-5)
    assert res.rotary_words > 0
    targets = geos_targets(parse_gcode(data), interior=False)
    reports = check_deposition(extrusion_chords(parse_gcode(new)), targets, parse_nozzle(ELLIPSE),
                               layers=[1, 2, 3, 4])
    assert len(reports) == 4
    for r in reports:
        assert r.max_outside <= 1e-3 + 2e-4, f"layer {r.layer}: {r.max_outside} mm outside"


def test_repeated_layers_share_a_tile_in_every_batch(union_sizes, monkeypatch):
    """The twins of a later batch share one tile too, though their first copy was built in
    an earlier batch: batches of two layers, one layer's beads each after the first."""
    data = _square_layers(5, first_differs=True)
    monkeypatch.setattr(pp_targets, "_BATCH_AREA", 400.0)  # two 12 mm tiles a batch
    _, res = postprocess_bytes(data, options=PostprocessOptions(nozzle=ELLIPSE, machine="ttr",
                                                                interior=False))
    n = [r.moves for r in res.layers]
    # (the batches' unions are built on threads, side by side: in either order)
    assert sorted(union_sizes) == sorted([n[0] + n[1], n[2], n[4]])

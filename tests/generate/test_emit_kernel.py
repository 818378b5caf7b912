"""The generator's compiled moves (:mod:`printability.generate._emit_kernel`) against the emitter.

The oracle is :class:`gcode.writer.Emitter` itself, driven as the generator drove it
before the kernel (``_travel`` then ``Emitter.extrude`` per piece): every byte and every
field of the state must agree.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_generate import ELLIPSE, TTR_PROFILE, _l_shape, _stack

import printability.generate.pipeline as gen
from gcode.writer import Emitter, WriterOptions
from printability.generate import GenerateOptions, generate_gcode
from printability.generate._emit_kernel import emit, hypot
from printability.sources import load_layers


def _python_run(em, cols, *, z, height, feed, travel, first_move):
    """The generator's loop over pieces with the emitter (its code before the kernel)."""
    for ax, ay, bx, by, phi, w, fold in zip(*cols, strict=True):
        if em.x is None or math.hypot(ax - em.x, ay - em.y) > 1e-6 or first_move:
            gen._travel(em, (ax, ay), z, None if math.isnan(phi) else phi, *travel)
            first_move = False
        em.extrude(bx, by, feed=feed, width=w, height=height,
                   orientation=None if math.isnan(phi) else phi,
                   turn_while_moving=None if math.isnan(fold) else fold)
    return first_move


def _state(em):
    return (em.x, em.y, em.z, em.angle, em.e, em._e_written, em._feed_written, em.rotations)


def test_hypot_is_pythons_to_the_bit():
    rng = np.random.default_rng(7)
    a = np.concatenate([rng.normal(size=20_000) * s for s in (1e-9, 1e-3, 1.0, 1e3, 1e9)])
    b = np.concatenate([rng.normal(size=20_000) * s for s in (1e-9, 1e-3, 1.0, 1e3, 1e9)])
    rng.shuffle(b)
    edge = [(0.0, 0.0), (3.0, 4.0), (-3.0, 4.0), (5e-324, 0.0), (1e-310, 2e-310),
            (1e308, 1e308), (math.inf, math.nan), (math.nan, 1.0), (0.0, -2.5)]
    pairs = list(zip(a.tolist(), b.tolist(), strict=True)) + edge
    got = [hypot(x, y) for x, y in pairs]
    want = [math.hypot(x, y) for x, y in pairs]
    same = [g == w or (math.isnan(g) and math.isnan(w)) for g, w in zip(got, want, strict=True)]
    assert all(same), [p for p, s in zip(pairs, same, strict=True) if not s][:5]


def _pieces(n, *, seed, turns=True):
    """Pieces of a path with what the generator meets: joined runs, short and long jumps,
    repeated points, turns small and large, splits (NaN fold)."""
    rng = np.random.default_rng(seed)
    cols = [[] for _ in range(7)]
    x, y = 10.0, 10.0
    for k in range(n):
        jump = rng.choice([0.0, 0.0, 0.0, 1e-7, 0.3, 5.0])
        ax, ay = x + jump * rng.normal(), y + jump * rng.normal()
        step = rng.choice([1e-5, 0.05, 0.4, 3.0])
        bx, by = ax + step * rng.normal(), ay + step * rng.normal()
        phi = float(rng.uniform(-400, 400)) if turns else math.nan
        if turns and k and rng.random() < 0.4:
            phi = cols[4][-1] + float(rng.choice([0.0, 1e-4, 5.0, 30.0]))
        fold = float(rng.choice([math.nan, 2.0, 25.0])) if turns else math.nan
        for c, v in zip(cols, (ax, ay, bx, by, phi, float(rng.uniform(0.2, 0.9)), fold),
                        strict=True):
            c.append(v)
        x, y = bx, by
    return cols


@pytest.mark.parametrize("options", [
    WriterOptions(period=180.0),
    WriterOptions(period=180.0, relative_e=False, feed_policy="euclidean"),
    WriterOptions(period=360.0, unwind=True, angle_min=-200.0, angle_max=200.0, letter="A"),
    WriterOptions(period=180.0, bead_model="rectangle", xy_decimals=3, e_decimals=4,
                  angle_decimals=1, feed_decimals=1, rotary_feed=900.0),
    WriterOptions(period=0.0),
], ids=["ellipse", "absolute-euclidean", "bounded-unwind", "decimals", "round"])
@pytest.mark.parametrize(("lift", "travel_feed"), [(0.0, 9000.0), (0.4, 9000.0), (0.0, 1800.0)])
def test_emit_writes_what_the_emitter_writes(options, lift, travel_feed):
    cols = _pieces(400, seed=int(lift * 10) + int(options.period), turns=options.rotary)
    travel = (travel_feed, 0.8, 2100.0, 1.0, lift)  # 1800: the feed of the extrusions
    runs = []
    for compiled in (True, False):
        em = Emitter(options)
        em.preamble()
        first = True
        for part in (slice(0, 150), slice(150, 400)):  # state carried between calls
            piece = [c[part] for c in cols]
            kw = {"z": 0.2, "height": 0.2, "feed": 1800.0, "travel": travel,
                  "first_move": first}
            done = emit(em, *piece, **kw) if compiled else None
            first = done if done is not None else _python_run(em, piece, **kw)
            assert compiled == (done is not None)
        runs.append((em.text(), _state(em), first))
    assert runs[0] == runs[1]


def test_emit_declines_what_it_does_not_compile():
    cols = _pieces(5, seed=1)
    kw = {"z": 0.2, "height": 0.2, "feed": 1800.0, "travel": (9000.0, 0.8, 2100.0, 1.0, 0.0),
          "first_move": True}
    em = Emitter(WriterOptions(period=180.0, feed_policy="inverse-time"))
    assert emit(em, *cols, **kw) is None and em.lines == []
    # an orientation the axis cannot reach: declined with the emitter untouched, which
    # then raises its own error
    em = Emitter(WriterOptions(period=360.0, angle_min=0.0, angle_max=10.0))
    cols[4] = [200.0] * 5
    assert emit(em, *cols, **kw) is None and em.lines == [] and em.x is None
    with pytest.raises(ValueError, match="cannot be reached"):
        _python_run(em, cols, **kw)


def _python_only(monkeypatch):
    monkeypatch.setattr(gen, "emit", lambda *a, **k: None)
    monkeypatch.setattr(gen, "measures", lambda footprints: False)


@pytest.mark.parametrize(("nozzle", "machine", "options"), [
    (ELLIPSE, "ttr", GenerateOptions(center=False)),
    ("rect:w=0.8,h=0.3", "ttr", GenerateOptions(center=False, relative_e=False)),
    ("circle:d=0.4", "xy", GenerateOptions(center=False)),
    (ELLIPSE, str(TTR_PROFILE), GenerateOptions(feed_policy="euclidean", unwind=True)),
])
def test_generate_compiled_equals_python(nozzle, machine, options, monkeypatch):
    stack = _stack(_l_shape(), _l_shape(), _l_shape())
    fast, _ = generate_gcode(stack, nozzle, machine, options=options)
    _python_only(monkeypatch)
    slow, _ = generate_gcode(stack, nozzle, machine, options=options)
    assert fast == slow


def test_generate_compiled_equals_python_on_a_real_part(monkeypatch, shared_data):
    layers = load_layers(shared_data / "stl" / "ThinWall.stl", layer_height=0.2)
    layers = dataclasses.replace(layers, layers=layers.layers[:6])
    fast, res = generate_gcode(layers, ELLIPSE, "ttr")
    assert res.rotations > 100 and res.dropped_length > 0  # turns, splits and drops
    _python_only(monkeypatch)
    slow, _ = generate_gcode(layers, ELLIPSE, "ttr")
    assert fast == slow

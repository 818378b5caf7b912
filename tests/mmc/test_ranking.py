"""Ranking nozzles by lost material, then by estimated build time."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import given
from hypothesis import settings as hyp_settings
from hypothesis import strategies as st
from shapes import comb, rectangle, u_shape

from printability.analysis.ranking import RankRow, bead_width_for_time, rank
from printability.errors import InputError
from printability.mmc import compute_mmc
from printability.model.nozzle import parse_nozzle
from printability.settings import Settings


def exact(g, spec, machine="xy"):
    return compute_mmc(g, spec, machine, engine="exact")


def test_less_lost_ranks_first_whatever_the_input_order():
    g = comb()
    specs = ["circle:d=1.0", "circle:d=0.25", "circle:d=0.6"]
    rows = rank([exact(g, s) for s in specs])
    assert [r.spec for r in rows] == ["circle:d=0.25", "circle:d=0.6", "circle:d=1.0"]
    assert [r.rank for r in rows] == [1, 2, 3]
    assert all(isinstance(r, RankRow) for r in rows)
    assert rows[0].lost <= rows[1].lost <= rows[2].lost
    with pytest.raises(dataclasses.FrozenInstanceError):
        rows[0].rank = 5  # type: ignore[misc]


def test_ties_go_to_the_faster_nozzle():
    # both rectangles fit every corner of a 10×4 rectangle: nothing lost, so the wider bead wins
    g = rectangle(10.0, 4.0)
    narrow, wide = exact(g, "rect:w=0.4,h=0.4"), exact(g, "rect:w=1.0,h=1.0")
    rows = rank([narrow, wide])
    assert rows[0].lost == pytest.approx(0.0, abs=1e-9) == rows[1].lost
    assert [r.spec for r in rows] == ["rect:w=1.0,h=1.0", "rect:w=0.4,h=0.4"]
    assert rows[0].build_time < rows[1].build_time
    # the model: area / (bead width × speed); a unit square's mean width over
    # directions is the mean of |cos| + |sin|, 4/π
    assert rows[0].build_time == pytest.approx(40.0 / (4 / math.pi * 40.0), rel=1e-3)


def test_build_time_model_uses_the_widest_bead_on_a_rotary_axis():
    noz = parse_nozzle("ellipse:major=0.8,minor=0.3")
    assert bead_width_for_time(noz, rotary=True) == pytest.approx(0.8, rel=1e-6)
    xy = bead_width_for_time(noz, rotary=False)
    assert 0.3 < xy < 0.8
    assert bead_width_for_time(parse_nozzle("circle:d=0.4"), rotary=False) == pytest.approx(0.4)
    two = parse_nozzle("circle:d=0.4,x=-5+circle:d=0.4,x=5")
    assert bead_width_for_time(two, rotary=False) == pytest.approx(0.8)


def test_layer_lists_rank_by_volume_with_heights():
    layers = [u_shape(), u_shape(gap=1.0), u_shape(gap=3.0)]
    per_nozzle = {s: [exact(g, s) for g in layers] for s in ("circle:d=0.4", "circle:d=1.5")}
    rows = rank(list(per_nozzle.values()), heights=[0.2, 0.2, 0.3])
    assert rows[0].spec == "circle:d=0.4" and rows[0].layers == 3 and rows[0].unit == "mm³"
    expected = sum(r.lost_area * h for r, h in zip(per_nozzle["circle:d=1.5"], [0.2, 0.2, 0.3],
                                                   strict=True))
    assert rows[1].lost == pytest.approx(expected)
    lo, hi = rows[1].lost_bounds
    assert lo <= rows[1].lost <= hi
    summed = rank(list(per_nozzle.values()))
    assert summed[0].unit == "mm²"
    assert summed[1].lost == pytest.approx(sum(r.lost_area for r in per_nozzle["circle:d=1.5"]))


def test_single_results_and_layer_lists_mix():
    g = u_shape()
    rows = rank([exact(g, "circle:d=0.4"), [exact(g, "circle:d=2")]])
    assert [r.layers for r in rows] == [1, 1]


@pytest.mark.parametrize("bad,kw,match", [
    ([], {}, "no nozzle results"),
    ([[]], {}, "no layer results"),
    (["circle:d=0.4"], {}, "expected MMCResult"),
    (None, {"speed": 0.0}, "speed"),
    (None, {"heights": [0.2, 0.2]}, "heights were given"),
    (None, {"heights": [-0.2]}, "positive layer thicknesses"),
])
def test_bad_input_is_refused_clearly(bad, kw, match):
    if bad is None:
        bad = [exact(u_shape(), "circle:d=0.4")]
    with pytest.raises(InputError, match=match):
        rank(bad, **kw)


def test_an_entry_mixing_nozzles_is_refused():
    g = u_shape()
    with pytest.raises(InputError, match="mixes nozzles"):
        rank([[exact(g, "circle:d=0.4"), exact(g, "circle:d=0.6")]])


# -- certified ranks: what the bounds establish -----------------------------------------------

def test_certified_ranks_of_disjoint_overlapping_and_touching_intervals():
    from printability.analysis.ranking import certified_ranks, rank_label, ties

    bounds = [(0.0, 1.0), (2.0, 3.0), (2.5, 4.0), (4.0, 5.0)]
    assert certified_ranks(bounds) == [(1, 1), (2, 3), (2, 4), (3, 4)]
    # touching intervals do not separate: both exact values could be 4.0
    assert ties(bounds) == [(1, 2), (2, 3)]
    assert [rank_label(r) for r in certified_ranks(bounds)] == ["1", "2–3", "2–4", "3–4"]
    assert certified_ranks([(1.0, 1.0), (1.0, 1.0)]) == [(1, 2), (1, 2)]


@given(st.lists(st.tuples(st.floats(0, 100), st.floats(0, 50), st.floats(0, 1)),
                min_size=1, max_size=7))
@hyp_settings(max_examples=200, deadline=None)
def test_the_exact_values_rank_within_the_certified_ranges(items):
    """Whatever the exact values inside their intervals, their true ranks lie in the ranges."""
    from printability.analysis.ranking import certified_ranks

    bounds = [(lo, lo + w) for lo, w, _ in items]
    exact = [lo + t * w for lo, w, t in items]
    ranges = certified_ranks(bounds)
    order = sorted(range(len(items)), key=lambda i: exact[i])
    for place, i in enumerate(order, 1):
        # with equal exact values any order among them is a true ranking: check the span
        first = 1 + sum(1 for v in exact if v < exact[i])
        last = sum(1 for v in exact if v <= exact[i])
        best, worst = ranges[i]
        assert best <= first and last <= worst, (bounds, exact, ranges)
        assert first <= place <= last


def test_rank_says_which_places_are_certain():
    # the exact engine is tight: a 0.25 and a 1.0 mm circle on a comb are far apart
    g = comb()
    rows = rank([exact(g, "circle:d=1.0"), exact(g, "circle:d=0.25")])
    assert [r.rank_range for r in rows] == [(1, 1), (2, 2)]
    assert all(r.rank_certain and r.tied_with == () for r in rows)
    # the raster engine's coarse intervals overlap: a tie, said so
    coarse = [compute_mmc(g, s, "xy", engine="raster", settings=Settings(resolution=0.2))
              for s in ("circle:d=0.6", "circle:d=0.5")]
    rows = rank(coarse)
    lo0, hi0 = rows[0].lost_bounds
    lo1, hi1 = rows[1].lost_bounds
    assert lo1 <= hi0 and lo0 <= hi1  # the intervals overlap...
    assert [r.rank_range for r in rows] == [(1, 2), (1, 2)]  # ...so no order is certain
    assert rows[0].tied_with == (rows[1].spec,) and not rows[0].rank_certain

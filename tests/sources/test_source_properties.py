"""Properties of the shared machinery: ring nesting, fill rules, mesh sections (hypothesis)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from printability.sources._common import fill_rings, nest_even_odd
from printability.sources.mesh import section_region


@st.composite
def _non_crossing_boxes(draw):
    """Axis-aligned rectangles that are pairwise nested or disjoint (never crossing)."""
    boxes: list[shapely.Polygon] = []
    for _ in range(draw(st.integers(1, 12))):
        x0 = draw(st.integers(0, 40))
        y0 = draw(st.integers(0, 40))
        w = draw(st.integers(1, 20))
        h = draw(st.integers(1, 20))
        b = shapely.box(x0, y0, x0 + w, y0 + h)
        if all(b.within(o) or o.within(b) or b.disjoint(o) for o in boxes) and not any(
                b.equals(o) for o in boxes):
            boxes.append(b)
    return boxes


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_non_crossing_boxes(), st.booleans())
def test_nesting_equals_even_odd_winding(boxes, reverse):
    rings = [np.asarray(b.exterior.coords)[:: -1 if reverse else 1] for b in boxes]
    nested = shapely.union_all(nest_even_odd(rings)) if boxes else shapely.Polygon()
    oracle = fill_rings(rings, "evenodd")
    assert nested.symmetric_difference(oracle).area < 1e-9
    # Depth parity by brute force at a few points.
    for x, y in ((0.5, 0.5), (10.5, 10.5), (20.25, 30.75), (35.5, 12.5)):
        depth = sum(b.contains(shapely.Point(x, y)) for b in boxes)
        assert nested.contains(shapely.Point(x, y)) == (depth % 2 == 1)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.floats(0.3, 1.0), min_size=5, max_size=24), st.floats(0.05, 0.95))
def test_section_of_a_prism_is_its_profile(radii, frac):
    # A star-shaped profile extruded 3 mm: every section is the profile itself.
    n = len(radii)
    pts = [(10 * r * math.cos(2 * math.pi * k / n), 10 * r * math.sin(2 * math.pi * k / n))
           for k, r in enumerate(radii)]
    profile = shapely.Polygon(pts)
    prism = trimesh.creation.extrude_polygon(profile, height=3.0)
    assert prism.is_watertight
    region = section_region(prism, 3.0 * frac)
    assert region.symmetric_difference(profile).area < 1e-9 * profile.area + 1e-12


@pytest.mark.parametrize("rule", ["nonzero", "evenodd"])
def test_fill_rules_on_a_doubly_wound_ring(rule):
    # One square traversed twice: winding number 2 inside.
    sq = np.array([(0, 0), (4, 0), (4, 4), (0, 4)] * 2, dtype=float)
    area = fill_rings([sq], rule).area
    assert area == pytest.approx(16.0 if rule == "nonzero" else 0.0)

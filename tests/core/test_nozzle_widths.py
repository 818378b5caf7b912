"""Nozzle.bead_widths (many moves at once) against Nozzle.bead_width (one at a time)."""

from __future__ import annotations

import numpy as np
import pytest

from printability.model.nozzle import parse_nozzle

SPECS = [
    "circle:d=0.4",
    "ellipse:major=0.8,minor=0.3",
    "ellipse:major=0.8,minor=0.3,angle=17,x=0.1,y=-0.05",
    "rect:w=0.8,h=0.3,rot=30",
    "polygon:pts=0 0;1 0;1 0.3",
    "ellipse:major=0.8,minor=0.3,x=-1+rect:w=0.5,h=0.2,x=1",
]


@pytest.mark.parametrize("spec", SPECS)
def test_bead_widths_equal_bead_width_elementwise(spec):
    noz = parse_nozzle(spec)
    rng = np.random.default_rng(3)
    direction = rng.uniform(-180, 180, 200)
    angle = rng.uniform(-400, 400, 200)
    many = noz.bead_widths(direction, angle)
    one = np.array([noz.bead_width(d, a) for d, a in zip(direction, angle, strict=True)])
    assert many.shape == (200,)
    np.testing.assert_allclose(many, one, rtol=0, atol=1e-12)


def test_bead_widths_broadcast_a_scalar_angle():
    noz = parse_nozzle("ellipse:major=0.8,minor=0.3")
    # across the motion: the major axis along the move lays the minor width, and back
    w = noz.bead_widths(np.array([0.0, 90.0]), 0.0)
    np.testing.assert_allclose(w, [0.3, 0.8], atol=1e-12)

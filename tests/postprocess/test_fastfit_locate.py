"""Point location in a bead union by the fused search (printability.planning._point_location).

The fused search first asks whether a point lies well within a bead's radius of its
axis (``_near_axis``): a shortcut of the polygon test (``in_polygons``) that may only
save time, never change an answer.
"""

from __future__ import annotations

import numpy as np
import pytest

from printability.planning._point_location import _AXIS, _near_axis, locate
from printability.planning.beadunion import bead_union, in_polygons
from printability.planning.fastfit import boundary_grid, locator

TAU = 0.95e-3


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_near_axis_is_a_shortcut_of_the_polygon_test(seed):
    """Wherever the axis test says inside, a bead polygon holds the point; it says so on
    the axes and just inside the beads' radius; and the location answers as the polygons,
    in particular just outside the radius and outside every bead."""
    rng = np.random.default_rng(seed)
    n = 40
    p0 = rng.uniform(0, 6, (n, 2))
    p1 = p0 + rng.normal(0, 0.8, (n, 2))
    p1[:3] = p0[:3]  # zero-length beads (a dot)
    r = rng.choice([0.2, 0.225, 0.3], n)
    u = bead_union(p0, p1, r, grow=TAU)
    loc = locator(u)
    ax, ay, bx, by, rho = loc.beads
    grid = boundary_grid(u)
    # points on the axes, then at a distance from them just in and just out of rho
    i = rng.integers(0, n, 6000)
    t = rng.uniform(0, 1, i.size)
    px = ax[i] + t * (bx[i] - ax[i])
    py = ay[i] + t * (by[i] - ay[i])
    side = rng.uniform(0, 2 * np.pi, i.size)
    dist = np.where(np.arange(i.size) < 2000, 0.0,
                    rho[i] * (1.0 + rng.choice([-1e-3, -1e-5, -1e-8, 0.0, 1e-8, 1e-5], i.size)))
    px = np.concatenate([px + dist * np.cos(side), rng.uniform(-1, 7, 2000)])
    py = np.concatenate([py + dist * np.sin(side), rng.uniform(-1, 7, 2000)])
    near = 0
    for k in range(px.size):
        poly = in_polygons(px[k], py[k], loc.polygons, loc.cells)
        fast = _near_axis(px[k], py[k], loc.cells, loc.beads)
        assert not fast or poly, k
        assert locate(px[k], py[k], grid, loc) == poly, k
        if k < 2000 or (k < 6000 and dist[k] < rho[i[k]] - 2 * _AXIS):
            assert fast, k
        near += fast
    assert near > 3000

"""Regression: kernels whose rows are longer than 128 pixels (a nozzle much wider than h).

The bit-parallel erosion reads runs through doubling tables that are only defined for
runs of up to 64 pixels; longer runs must be split. Unsplit, P kept positions where the
footprint leaves G (an MMC violation) and the bounds missed the exact value.
"""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from shapes import star

from printability.mmc import compute_mmc
from printability.model.nozzle import parse_nozzle
from printability.settings import Settings


@pytest.mark.parametrize("spec", ["rect:w=0.75,h=0.7", "rect:w=0.7,h=0.7,angle=30",
                                  "circle:d=0.72"])
def test_long_kernel_runs_keep_the_promise(spec):
    g = shapely.affinity.scale(star(), 0.5, 0.5, origin=(0, 0))
    h = 0.005  # the nozzle spans ~140 pixels
    r = compute_mmc(g, spec, "xy", engine="raster", settings=Settings(resolution=h))
    exact = compute_mmc(g, spec, "xy", engine="exact")
    lo, hi = r.lost_area_bounds
    assert lo <= exact.lost_area_bounds[1] and exact.lost_area_bounds[0] <= hi
    mask = r.motion.mask(0)
    xs, ys = mask.grid.centers()
    iy, ix = np.nonzero(mask.data)
    pick = np.random.default_rng(0).choice(len(ix), size=min(4000, len(ix)), replace=False)
    fp = np.asarray(parse_nozzle(spec).outline(0, mode="outer").exterior.coords)
    placed = [shapely.Polygon(fp + np.array([xs[ix[k]], ys[iy[k]]])) for k in pick]
    assert shapely.within(np.array(placed), g).all()

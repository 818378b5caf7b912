"""The raster engine against independent oracles: the exact vector engine, shapely
buffers, and real data (slices of printed parts, coastlines).

Both engines' intervals contain the exact lost area, so they must overlap; the
exact engine's interval is tight, so this checks the raster bounds for real.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import shapely
from shapes import catalogue, load_coastline, load_slice

from printability.mmc import compute_mmc
from printability.settings import Settings

CATALOGUE = catalogue()


def _both(region, nozzle, machine, h):
    exact = compute_mmc(region, nozzle, machine, engine="exact")
    ras = compute_mmc(region, nozzle, machine, engine="raster",
                      settings=Settings(resolution=h))
    return exact, ras


def _assert_overlap(exact, ras):
    elo, ehi = exact.lost_area_bounds
    rlo, rhi = ras.lost_area_bounds
    assert rlo <= ehi + 1e-9 and elo <= rhi + 1e-9, (exact.lost_area_bounds, ras.lost_area_bounds)
    assert rlo <= ras.lost_area <= rhi


def _cases():
    for name in sorted(CATALOGUE):
        yield pytest.param(name, "circle:d=0.6", "xy", id=f"{name}-circle-xy")
        # the exact engine takes seconds per real slice on T-T-R: those run with -m slow
        marks = [pytest.mark.slow] if name.startswith("slice:") else []
        yield pytest.param(name, "ellipse:major=0.8,minor=0.3", "ttr:step=15",
                           id=f"{name}-ellipse-ttr", marks=marks)


@pytest.mark.parametrize("name,nozzle,machine", list(_cases()))
def test_bounds_overlap_the_exact_engine_on_the_catalogue(name, nozzle, machine):
    region = CATALOGUE[name].region
    if region.area < 1.0:
        pytest.skip("too small for this nozzle")
    exact, ras = _both(region, nozzle, machine, h=0.04)
    _assert_overlap(exact, ras)
    # both are safe: the raster's as-built layer lies inside the exact engine's outer one
    # up to the exact engine's own certified slack
    assert ras.as_built.difference(region).area == 0.0


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_bounds_overlap_the_exact_engine_fine_angles(name):
    exact, ras = _both(CATALOGUE[name].region, "ellipse:major=0.8,minor=0.3", "ttr:step=2",
                       h=0.02)
    _assert_overlap(exact, ras)


def test_circle_bounds_contain_a_fine_shapely_opening_on_real_slices(shared_data: Path):
    """Circle on XY: the exact lost area is within a tiny tolerance of a fine shapely opening."""
    files = sorted((shared_data / "slices").glob("*.txt"))
    assert len(files) >= 300
    rng = np.random.default_rng(7)
    for path in rng.choice(files, size=4, replace=False):
        region, _, wmax = load_slice(path)
        r = wmax / 2
        if region.area < math.pi * r * r:
            continue
        ras = compute_mmc(region, f"circle:d={wmax}", "xy", engine="raster",
                          settings=Settings(resolution=0.03))
        opened = region.buffer(-r, quad_segs=64).buffer(r, quad_segs=64)
        # chords of 64 segments per quarter: each buffer is within r·(1 − cos(π/256)) of exact
        tol = 2 * r * (1 - math.cos(math.pi / 256)) * (region.length + opened.length)
        lost = region.area - opened.intersection(region).area
        lo, hi = ras.lost_area_bounds
        assert lo - tol <= lost <= hi + tol, (path.name, lo, lost, hi)


def test_coastline_ttr_overlaps_exact(shared_data: Path):
    japan = load_coastline("japan_110m", size=30.0, keep=3)
    exact, ras = _both(japan, "ellipse:major=0.8,minor=0.3", "ttr:step=30", h=0.04)
    _assert_overlap(exact, ras)


@pytest.mark.slow
def test_coastline_japan_10m_at_benchmark_size(shared_data: Path):
    japan = load_coastline("japan_10m", size=100.0, keep=4)
    exact, ras = _both(japan, "ellipse:major=1.6,minor=0.6", "ttr:step=10", h=0.04)
    _assert_overlap(exact, ras)
    assert ras.as_built_raster is not None


def test_raster_converges_to_exact_as_h_shrinks():
    region = CATALOGUE["star"].region
    exact = compute_mmc(region, "circle:d=0.8", "xy", engine="exact")
    target = 0.5 * sum(exact.lost_area_bounds)
    errs = []
    for h in (0.04, 0.02, 0.01):
        ras = compute_mmc(region, "circle:d=0.8", "xy", engine="raster",
                          settings=Settings(resolution=h))
        _assert_overlap(exact, ras)
        errs.append(abs(ras.lost_area - target))
        width = ras.lost_area_bounds[1] - ras.lost_area_bounds[0]
        assert width < 3.0 * region.length * h  # O(perimeter · h)
    assert errs[-1] < errs[0] or errs[-1] < 0.01 * region.area
    assert shapely.is_valid(ras.as_built)

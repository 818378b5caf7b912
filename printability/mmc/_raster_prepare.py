"""Inputs of the raster MMC engine: conservative raster of G, sampled angles and kernels.

The notation (pixels Q_ij, kernel offsets d and their pixels Q'_d), the
angular margin δ and the kernels K_touch, K_full, K_need, K_dil and K_c built
here are those of :mod:`printability.mmc.raster`, which proves the bounds
they give.

Conservative rasterisation of G
    Every pixel is *inside* (I: ∂G is farther than eps from the closed pixel
    and its centre is inside by even–odd parity, so Q ⊆ int G), *outside*
    (∂G is farther than eps and the centre is outside, so Q ∩ G = ∅) or *cut*
    (C: ∂G comes within eps of Q; a superset of the pixels ∂G truly meets).
    Every pixel also gets its exact covered fraction cov = λ(Q ∩ G)/h² by
    signed-area accumulation (:func:`_raster_kernels.coverage_rings`), so areas
    are exact sums. Pixels wrongly called cut only make both results more
    cautious.

Buffers by ±δ
    The outer kernels use core_k = inner outline ⊖ D(δ) and F_k ⊕ D(δ).
    Buffers by ±δ are made with a radius δ/κ, κ = cos(3π/(8·16)) − 1.05·10⁻³:
    GEOS fillet chords (16 per quarter circle, each spanning at most 1.5
    quanta) keep ≥ κ·radius from the arc's centre, its end-point snapping
    moves ≤ 10⁻³·radius, and its shallow-concavity simplifier only cuts the
    offset side (the analysis of :mod:`printability.mmc._disk_offsets`), so the
    grown footprint contains F ⊕ D(δ) and the core lies in F ⊖ D(δ).

Floating point: classification uses eps = 1e-6·h + 1e-12·(coordinate size),
far above the rounding of the crossing computations; coverage sums are exact
to ~1e-13 per pixel (the engine widens lo and hi by 1e-9·λ(G) to absorb that).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from printability.errors import ResourceError
from printability.mmc._raster_kernels import (
    classify_rings,
    coverage_rings,
)
from printability.model.geometry import Grid, polygons_of
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle
from printability.settings import DEFAULT_SETTINGS, Settings

__all__ = [
    "RasterProblem",
    "check_memory",
    "estimate_memory",
    "prepare_raster",
    "rasterize_region",
]

# shapely's buffer arcs use this many segments per quarter circle; the ±δ buffers are
# inflated by 1/κ so their chords (and GEOS's snapping) never cross the true arc
_BUFFER_QS = 16
_BUFFER_KAPPA = math.cos(3 * math.pi / (8 * _BUFFER_QS)) - 1.05e-3


def oriented_rings(geom: BaseGeometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed rings of a polygonal geometry, shells CCW and holes CW, concatenated."""
    xs, ys, starts = [], [], [0]
    for poly in polygons_of(geom):
        poly = shapely.geometry.polygon.orient(poly, 1.0)
        for ring in (poly.exterior, *poly.interiors):
            c = np.asarray(ring.coords, dtype=float)
            xs.append(c[:, 0])
            ys.append(c[:, 1])
            starts.append(starts[-1] + len(c))
    if len(starts) == 1:
        return np.zeros(0), np.zeros(0), np.zeros(1, np.int64)
    return np.concatenate(xs), np.concatenate(ys), np.asarray(starts, np.int64)


def _eps(h: float, scale: float) -> float:
    return 1e-6 * h + 1e-12 * scale


def rasterize_region(region: BaseGeometry, grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """Conservative classification and exact coverage of ``region`` on ``grid``.

    Returns
    -------
    cls : uint8 (ny, nx)
        0 outside (closed pixel disjoint from G), 1 cut with centre outside,
        2 cut with centre inside, 3 inside (closed pixel in the interior of G).
    cov : float64 (ny, nx)
        λ(pixel ∩ G) / h², exact up to rounding (1 on inside, 0 on outside pixels).

    Notes
    -----
    Cost O(nx·ny + Σ pixels crossed by ∂G); memory 19 bytes per pixel at peak.
    """
    xs, ys, starts = oriented_rings(region)
    scale = float(np.max(np.abs(np.concatenate([xs, ys])))) if len(xs) else 1.0
    cls = classify_rings(xs, ys, starts, grid.x0, grid.y0, grid.h, grid.nx, grid.ny,
                         _eps(grid.h, scale))
    cov = coverage_rings(xs, ys, starts, grid.x0, grid.y0, grid.h, grid.nx, grid.ny)
    np.negative(cov, out=cov)  # CCW shells accumulate negatively
    cut = (cls == 1) | (cls == 2)
    np.clip(cov, 0.0, 1.0, out=cov)
    cov[cls == 3] = 1.0
    cov[cls == 0] = 0.0
    del cut
    return cls, cov


def _classify_small(rings: tuple[np.ndarray, np.ndarray, np.ndarray], radius: int, h: float,
                    sx: float = 0.0, sy: float = 0.0) -> np.ndarray:
    """Classification of a footprint on the kernel grid: pixel [R+di, R+dj] is Q'_d + (sx, sy)."""
    n = 2 * radius + 1
    xs, ys, starts = rings
    if len(xs) == 0:
        return np.zeros((n, n), np.uint8)
    x0 = -(radius + 0.5) * h + sx
    y0 = -(radius + 0.5) * h + sy
    scale = float(np.max(np.abs(np.concatenate([xs, ys])))) + radius * h
    return classify_rings(xs, ys, starts, x0, y0, h, n, n, _eps(h, scale))


def _merged(geom: BaseGeometry) -> BaseGeometry:
    parts = polygons_of(geom)
    return parts[0] if len(parts) == 1 else shapely.union_all(parts)


@dataclass(frozen=True, eq=False)
class RasterProblem:
    """The rasterised inputs of the raster engine (also what the benchmark feeds OpenCV).

    Attributes
    ----------
    grid
        The grid (covers G grown by the nozzle radius, origin snapped to h).
    cls, cov
        See :func:`rasterize_region`.
    angles
        Sampled angles, degrees.
    angle_gap
        Δ, the largest gap between consecutive samples (wrap included), degrees.
    delta
        Angular margin ρ·Δ/2, mm.
    wrap
        Whether the last angle is adjacent to the first (full symmetry period).
    radius
        Kernel half-size R in pixels; every kernel is ``(2R+1, 2R+1)`` boolean with
        the nozzle origin at ``[R, R]`` and ``[R + di, R + dj]`` the offset d.
    touch, full, need, dil, centre
        Kernel stacks ``(n_angles, 2R+1, 2R+1)``: K_touch, K_full (inner pass),
        K_need, K_dil (outer pass), K_c (estimate); see :mod:`printability.mmc.raster`.
    """

    grid: Grid
    cls: np.ndarray
    cov: np.ndarray
    angles: np.ndarray
    angle_gap: float
    delta: float
    wrap: bool
    radius: int
    touch: np.ndarray
    full: np.ndarray
    need: np.ndarray
    dil: np.ndarray
    centre: np.ndarray


def _angular_cells(machine: Machine, nozzle: Nozzle, angles: np.ndarray) -> tuple[float, bool]:
    """(Δ in degrees, wrap) for the sampled angles."""
    period = nozzle.symmetry_period
    wrap = False
    if machine.turns(nozzle) and len(angles) > 1:
        span = machine.angle_max - machine.angle_min
        wrap = machine.full_turn or (0 < period < 360.0 and span >= period - 1e-9)
    if len(angles) < 2:
        return 0.0, False
    gaps = list(np.diff(angles))
    if wrap:
        gaps.append(angles[0] + min(period, 360.0) - angles[-1])
    return float(max(gaps)), wrap


def kernel_radius(nozzle: Nozzle, h: float, delta: float, quad_segs: int) -> int:
    reach = nozzle.radius / math.cos(math.pi / max(8, 4 * quad_segs)) + delta * 1.01 + 2 * h
    return math.ceil(reach / h) + 1


def _kernels(nozzle: Nozzle, angles: np.ndarray, h: float, delta: float, radius: int,
             quad_segs: int) -> dict[str, np.ndarray]:
    n = 2 * radius + 1
    stacks = {name: np.zeros((len(angles), n, n), bool)
              for name in ("touch", "full", "need", "dil", "centre")}
    grow = delta / _BUFFER_KAPPA * (1 + 1e-7) + 1e-12 if delta > 0 else 0.0
    half = 0.5 * h
    for k, phi in enumerate(angles):
        outer = _merged(nozzle.outline(float(phi), quad_segs=quad_segs, mode="outer"))
        inner = _merged(nozzle.outline(float(phi), quad_segs=quad_segs, mode="inner"))
        fine = _merged(nozzle.outline(float(phi), quad_segs=max(quad_segs, 64), mode="inner"))
        stacks["touch"][k] = _classify_small(oriented_rings(outer), radius, h) >= 1
        stacks["full"][k] = _classify_small(oriented_rings(inner), radius, h) == 3
        stacks["centre"][k] = _classify_small(oriented_rings(fine), radius, h) >= 2
        core = oriented_rings(inner.buffer(-grow, quad_segs=_BUFFER_QS) if grow > 0 else inner)
        grown = oriented_rings(outer.buffer(grow, quad_segs=_BUFFER_QS) if grow > 0 else outer)
        need = np.zeros((n, n), bool)
        for sx in (-half, 0.0, half):
            for sy in (-half, 0.0, half):
                need |= _classify_small(core, radius, h, sx, sy) == 3
        stacks["need"][k] = need
        dil = np.zeros((n, n), bool)
        for sx in (-half, half):
            for sy in (-half, half):
                dil |= _classify_small(grown, radius, h, sx, sy) >= 1
        stacks["dil"][k] = dil
    return stacks


def estimate_memory(grid: Grid, n_angles: int, radius: int, *, band_words: int | None = None
                    ) -> int:
    """Peak bytes the raster engine needs on ``grid``.

    ``band_words`` (when known) sizes the stored per-angle words; otherwise
    the worst case (every word at every angle) is assumed.
    """
    npx = grid.nx * grid.ny
    nw = (grid.nx + 63) // 64
    wbytes = grid.ny * nw * 8
    levels = max(1, math.ceil(math.log2(2 * radius + 2)))
    rasters = 20 * npx              # cls, coverage (+ its accumulator), toggles, temporaries
    words = (12 + 2 * levels) * wbytes  # inputs, unions, work masks, doubling tables
    stored = n_angles * (band_words if band_words is not None else grid.ny * nw) * 12
    results = 4 * npx               # count (uint16), as_built_raster, unpacking
    kernels = 6 * n_angles * (2 * radius + 1) ** 2
    return int(rasters + words + stored + results + kernels)


def check_memory(need: int, settings: Settings, what: str) -> None:
    if need > settings.max_memory:
        raise ResourceError(
            f"the raster engine would need about {need / 2**20:,.0f} MiB for {what}, more than "
            f"the {settings.max_memory / 2**20:,.0f} MiB allowed (Settings.max_memory); use a "
            "coarser resolution, a larger angle step, or raise the limit"
        )


def prepare_raster(region: BaseGeometry, nozzle: Nozzle, machine: Machine, *,
                   settings: Settings = DEFAULT_SETTINGS) -> RasterProblem:
    """Grid, conservative raster of G, sampled angles and all kernels.

    Raises
    ------
    ResourceError
        When the estimated memory exceeds ``settings.max_memory`` (checked
        before any raster is allocated).
    """
    h = float(settings.resolution)
    angles = np.asarray(machine.angles(step=settings.angle_step,
                                       period=nozzle.symmetry_period), dtype=float)
    gap, wrap = _angular_cells(machine, nozzle, angles)
    delta = nozzle.radius * math.radians(gap) / 2.0
    radius = kernel_radius(nozzle, h, delta, settings.quad_segs)
    minx, miny, maxx, maxy = region.bounds
    # P may lie up to the nozzle radius outside G (offset nozzles): grow the grid by it.
    margin = nozzle.radius + delta + 2 * h
    nx_est = math.ceil((maxx - minx + 2 * margin) / h) + 1
    ny_est = math.ceil((maxy - miny + 2 * margin) / h) + 1
    fake = Grid(0.0, 0.0, h, max(nx_est, 1), max(ny_est, 1))
    # the per-angle words are sized (and checked again) once the band is known
    check_memory(estimate_memory(fake, len(angles), radius, band_words=0), settings,
                 f"a {nx_est} × {ny_est} grid at h = {h:g} mm with {len(angles)} angles")
    grid = Grid.covering(region.bounds, h, margin=margin)
    cls, cov = rasterize_region(region, grid)
    stacks = _kernels(nozzle, angles, h, delta, radius, settings.quad_segs)
    return RasterProblem(grid, cls, cov, angles, gap, delta, wrap, radius, **stacks)


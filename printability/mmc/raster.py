"""Raster MMC engine: bit-parallel morphology on a conservative raster, with proven bounds.

The fast engine for a separable machine (XY, T-T-R) and any nozzle. On a grid
of spacing h it computes, per sampled angle φ_k, the motion restriction
P_φk = G ⊖ R(φ_k)A⁰ and the as-built layer S = ∪_k (P_φk ⊕ R(φ_k)A⁰), three
times: an *inner* result that never puts material outside G, an *outer*
result that contains everything the machine could print at any angle, and a
centre-sampled *estimate* in between. The lost area λ(G \\ S) is reported
with bounds [lo, hi] that contain the exact value of the continuous problem
(every position, every angle of the machine's range) and of the problem at
the sampled angles.

Notation
--------
Pixels are the closed squares Q_ij of the Grid (see :mod:`printability.geometry`
for the axis order), c_ij their centres. A kernel offset d = (di, dj) is the
pixel Q'_d = [(dj−½)h, (dj+½)h] × [(di−½)h, (di+½)h] about the nozzle origin;
placing a set at c_ij moves Q'_d onto Q_{(i,j)+d}. Erosion is without
reflection, ``(X ⊖ K)(c) = ∧_{d∈K} X(c + d)``, and dilation
``(P ⊕ K)(s) = ∨_{d∈K} P(s − d)``, as in the geometry module.

Conservative rasterisation of G
    Every pixel is *inside* (I: ∂G is farther than eps from the closed pixel
    and its centre is inside by even–odd parity, so Q ⊆ int G), *outside*
    (∂G is farther than eps and the centre is outside, so Q ∩ G = ∅) or *cut*
    (C: ∂G comes within eps of Q; a superset of the pixels ∂G truly meets).
    Every pixel also gets its exact covered fraction cov = λ(Q ∩ G)/h² by
    signed-area accumulation (:func:`_raster_kernels.coverage_rings`), so areas
    are exact sums. Pixels wrongly called cut only make both results more
    cautious.

Angular sampling
    The angles φ_k are ``machine.angles(step=settings.angle_step,
    period=nozzle.symmetry_period)``; Δ is the largest gap between consecutive
    samples (with the wrap-around gap on a full period). Every angle φ the
    machine can take is, modulo the nozzle's symmetry period, within Δ/2 of
    some φ_k. A turn by α moves a point at distance r ≤ ρ (ρ = nozzle.radius)
    by 2r·sin(α/2) ≤ ρ·α, so with δ = ρ·Δ/2 (Δ in radians):
    ``R(φ)A⁰ ⊆ R(φ_k)A⁰ ⊕ D(δ)`` and ``R(φ_k)A⁰ ⊖ D(δ) ⊆ R(φ)A⁰`` whenever
    |φ − φ_k| ≤ Δ/2 (D(δ) the disk; the second because q ⊕ D(δ) ⊆ R(φ_k)A⁰ and
    R(φ_k − φ)q is within δ of q). XY and round nozzles have one angle, δ = 0.

Inner result (hi)
    K_touch(k): offsets d whose Q'_d meets F_k = outline(φ_k, mode="outer")
    ⊇ R(φ_k)A⁰ (conservative superset). P_in(k) = I ⊖ K_touch(k): at such a
    c the footprint lies in a union of inside pixels, so c ∈ P_φk — the
    stored motion restriction never puts material outside G.
    K_full(k): offsets whose Q'_d lies in outline(φ_k, mode="inner") ⊆
    R(φ_k)A⁰ (a subset). S_in = ∪_k P_in(k) ⊕ K_full(k) consists of whole
    pixels each covered by a feasible footprint, so S_in ⊆ S_sampled ⊆ S ⊆ G
    and ``hi = λ(G) − h²·|S_in| ≥ λ(G \\ S_sampled) ≥ λ(G \\ S)``.

Outer result (lo)
    Let (t, φ) be any feasible configuration, t ∈ Q_ij, φ in the cell of φ_k,
    so t = c_ij + e with e ∈ B(h/2) (the half-cell box). Any q with
    q ⊕ B(h/2) ⊕ D(δ) ⊆ R(φ_k)A⁰ satisfies c_ij + q ∈ R(φ)A⁰ + t ⊆ G (as
    q − e ⊕ D(δ) ⊆ R(φ_k)A⁰, then turn). K_need(k) collects offsets d whose
    closed Q'_d holds such a q: the union over 9 shifts s ∈ {−h/2, 0, h/2}²
    of the pixels fully inside core_k = inner outline ⊖ D(δ) on the grid
    shifted by s (the box of side h about d·h + s lies in core_k, so
    q = d·h + s qualifies). Then Q_{(i,j)+d} meets G, so it is inside or cut:
    (i, j) ∈ P_out(k) = (I ∪ C) ⊖ K_need(k). The footprint lies in
    c_ij + B(h/2) + R(φ_k)A⁰ ⊕ D(δ); the pixels it can meet are the offsets
    K_dil(k) whose box of side 2h about d·h meets F_k ⊕ D(δ) (union over the
    4 corner shifts of the pixels touched). Hence
    S ⊆ ∪ pixels of S_out = (∪_k P_out(k) ⊕ K_dil(k)) ∩ (I ∪ C) and
    ``lo = λ(G) − Σ_{S_out} cov·h² ≤ λ(G \\ S) ≤ λ(G \\ S_sampled)``.
    Buffers by ±δ are made with a radius δ/κ, κ = cos(3π/(8·16)) − 1.05·10⁻³:
    GEOS fillet chords (16 per quarter circle, each spanning at most 1.5
    quanta) keep ≥ κ·radius from the arc's centre, its end-point snapping
    moves ≤ 10⁻³·radius, and its shallow-concavity simplifier only cuts the
    offset side (the analysis of :mod:`printability.mmc.exact`), so the
    grown footprint contains F ⊕ D(δ) and the core lies in F ⊖ D(δ).

Estimate
    The centre-sampled opening: B = pixels whose centre is in G, K_c(k) =
    offsets whose centre is in the footprint, S_est = ∪_k (B ⊖ K_c) ⊕ K_c;
    lost = h²·|B \\ S_est| (both sides sampled alike, so the sampling of ∂G
    cancels), clipped into [lo, hi]. It converges to the
    sampled-angle value as h → 0 (O(h) near ∂G, usually much better).

Floating point: classification uses eps = 1e-6·h + 1e-12·(coordinate size),
far above the rounding of the crossing computations; coverage sums are exact
to ~1e-13 per pixel; lo and hi are widened by 1e-9·λ(G) to absorb that.

Speed
    Masks are bit-packed, 64 pixels per ``uint64`` word. A footprint is a
    union of horizontal runs; eroding a word is the AND over runs of two
    reads of a doubling table (AND of 2^l consecutive pixels), so its cost is
    about 2 × rows of the kernel per 64 pixels, whatever the run lengths. Only
    the words in the band where P can change with the angle are computed
    (the pixels P holds at every angle, X ⊖ ∪_k K(k), are computed once, and
    P is empty outside X ⊖ ∩_k K(k)); a word stops at 0. The dilation only
    visits words with target pixels not yet in the union, stops once they
    are covered, and its target drops pixels no angle can reach: those not
    in (X ⊖ ∩_k K(k)) ⊕ ∪_k K_dil(k), and for the inner pass the pixels next
    to a non-inside pixel (a pixel wholly inside a closed footprint makes it
    touch the 8 neighbours, which must then be inside: S_in ⊆ I ⊖ 3×3). The
    outer and estimate passes store no P, so they erode only the band words
    a dilation can still read (near words with uncovered target pixels).
    All of it is exact: the benchmark checks every pixel against OpenCV.
    Cost per angle O(band words × kernel rows); memory ≈ 24 bytes per pixel
    plus 8 bytes per band word and angle.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import MultiPolygon
from shapely.geometry.base import BaseGeometry

from printability.errors import InputError, ResourceError
from printability.geometry import Grid, Raster, as_region, polygons_of
from printability.machine import Machine
from printability.mmc import _raster_kernels as _k
from printability.mmc.components import angle_ranges, component_labels
from printability.mmc.result import Components, MMCResult, MotionRestriction, PackedMasks
from printability.nozzle import Nozzle
from printability.settings import DEFAULT_SETTINGS, Settings

__all__ = [
    "RasterProblem",
    "estimate_memory",
    "mmc_raster",
    "prepare_raster",
    "rasterize_region",
]

# shapely's buffer arcs use this many segments per quarter circle; the ±δ buffers are
# inflated by 1/κ so their chords (and GEOS's snapping) never cross the true arc
_BUFFER_QS = 16
_BUFFER_KAPPA = math.cos(3 * math.pi / (8 * _BUFFER_QS)) - 1.05e-3
# booleans (n_angles·ny·nx bytes) up to which MotionRestriction.masks is filled too
_MASKS_LIMIT = 64 << 20
# runs up to which S_inner and the components are vectorised to shapely geometry
_VECTOR_RUNS = 400_000
_COMPONENT_RUNS = 400_000


# --------------------------------------------------------------------------- helpers


def _rings(geom: BaseGeometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
    xs, ys, starts = _rings(region)
    scale = float(np.max(np.abs(np.concatenate([xs, ys])))) if len(xs) else 1.0
    cls = _k.classify_rings(xs, ys, starts, grid.x0, grid.y0, grid.h, grid.nx, grid.ny,
                            _eps(grid.h, scale))
    cov = _k.coverage_rings(xs, ys, starts, grid.x0, grid.y0, grid.h, grid.nx, grid.ny)
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
    return _k.classify_rings(xs, ys, starts, x0, y0, h, n, n, _eps(h, scale))


def _merged(geom: BaseGeometry) -> BaseGeometry:
    parts = polygons_of(geom)
    return parts[0] if len(parts) == 1 else shapely.union_all(parts)


@dataclass(frozen=True)
class _Runs:
    """A kernel as horizontal runs for the word kernels: rows (dy, a, level, second)."""

    table: np.ndarray

    @property
    def max_level(self) -> int:
        return int(self.table[:, 2].max()) if len(self.table) else 0


def _mask_runs(mask: np.ndarray, radius: int) -> list[tuple[int, int, int]]:
    """(di, dj_start, length) of the True runs of a kernel mask."""
    padded = np.zeros((mask.shape[0], mask.shape[1] + 2), np.int8)
    padded[:, 1:-1] = mask
    rows, cols = np.nonzero(np.diff(padded, axis=1))
    starts, stops = cols[::2], cols[1::2]
    return list(zip((rows[::2] - radius).tolist(), (starts - radius).tolist(),
                    (stops - starts).tolist(), strict=True))


def _to_runs(runs: list[tuple[int, int, int]], *, dilate: bool, order_from_centre: bool
             ) -> _Runs:
    """Word-kernel runs; a dilation run reads row i − di from column j − dj − L + 1."""
    # Runs longer than 64 pixels are split: a doubling-table level l combines word w with
    # word w + 1 shifted by 2^(l-1) bits, which is only defined up to level 6 (32-bit
    # shift; a 64-bit shift of a uint64 is undefined). Unsplit 128+ pixel runs (a 1 mm
    # nozzle at h < 0.008 mm) made erosion keep infeasible positions.
    split = []
    for di, dj, L in runs:
        for s0 in range(0, L, 64):
            split.append((di, dj + s0, min(64, L - s0)))
    runs = split
    if dilate:
        # the dilation kernel reads row i − di from column j − dj − L + 1
        runs = [(-di, -dj - L + 1, L) for di, dj, L in runs]
    if runs:
        # erosion stops at 0: the runs far from the centre decide first; dilation stops when
        # covered: the central runs first.
        key = [abs(di) + abs(dj + L / 2) for di, dj, L in runs]
        order = np.argsort(key)
        if not order_from_centre:
            order = order[::-1]
        runs = [runs[t] for t in order]
    dy = np.array([r[0] for r in runs], np.int64)
    a = np.array([r[1] for r in runs], np.int64)
    L = np.array([r[2] for r in runs], np.int64)
    lev = np.floor(np.log2(np.maximum(L, 1))).astype(np.int64)
    m = np.left_shift(1, lev)
    second = np.where(L > m, L - m, -1).astype(np.int64)
    return _Runs(np.ascontiguousarray(np.column_stack([dy, a, lev, second]).reshape(-1, 4)))


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
        K_need, K_dil (outer pass), K_c (estimate); see the module docstring.
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
    if machine.kind == "ttr" and period != 0.0 and len(angles) > 1:
        span = machine.angle_max - machine.angle_min
        wrap = machine.full_turn or (0 < period < 360.0 and span >= period - 1e-9)
    if len(angles) < 2:
        return 0.0, False
    gaps = list(np.diff(angles))
    if wrap:
        gaps.append(angles[0] + min(period, 360.0) - angles[-1])
    return float(max(gaps)), wrap


def _kernel_radius(nozzle: Nozzle, h: float, delta: float, quad_segs: int) -> int:
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
        stacks["touch"][k] = _classify_small(_rings(outer), radius, h) >= 1
        stacks["full"][k] = _classify_small(_rings(inner), radius, h) == 3
        stacks["centre"][k] = _classify_small(_rings(fine), radius, h) >= 2
        core = _rings(inner.buffer(-grow, quad_segs=_BUFFER_QS) if grow > 0 else inner)
        grown = _rings(outer.buffer(grow, quad_segs=_BUFFER_QS) if grow > 0 else outer)
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


def _check_memory(need: int, settings: Settings, what: str) -> None:
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
    radius = _kernel_radius(nozzle, h, delta, settings.quad_segs)
    minx, miny, maxx, maxy = region.bounds
    # P may lie up to the nozzle radius outside G (offset nozzles): grow the grid by it.
    margin = nozzle.radius + delta + 2 * h
    nx_est = math.ceil((maxx - minx + 2 * margin) / h) + 1
    ny_est = math.ceil((maxy - miny + 2 * margin) / h) + 1
    fake = Grid(0.0, 0.0, h, max(nx_est, 1), max(ny_est, 1))
    # the per-angle words are sized (and checked again) once the band is known
    _check_memory(estimate_memory(fake, len(angles), radius, band_words=0), settings,
                  f"a {nx_est} × {ny_est} grid at h = {h:g} mm with {len(angles)} angles")
    grid = Grid.covering(region.bounds, h, margin=margin)
    cls, cov = rasterize_region(region, grid)
    stacks = _kernels(nozzle, angles, h, delta, radius, settings.quad_segs)
    return RasterProblem(grid, cls, cov, angles, gap, delta, wrap, radius, **stacks)


# --------------------------------------------------------------------------- passes


@dataclass
class _PassResult:
    union: np.ndarray        # packed S of the pass
    base: np.ndarray         # packed deep P (held at every angle)
    band_i: np.ndarray
    band_w: np.ndarray
    values: np.ndarray       # (n, nband) when stored, else (0, nband)


def _last_mask(nx: int) -> np.uint64:
    r = nx % 64
    return _k.ALL_ONES if r == 0 else np.uint64((1 << r) - 1)


def _opening_pass(inp: np.ndarray, target: np.ndarray, erode_k: np.ndarray, dilate_k: np.ndarray,
                  radius: int, nx: int, *, store: bool, tick: Callable[[], None],
                  check: Callable[[int], None] | None = None) -> _PassResult:
    """∪_k (inp ⊖ erode_k[k]) ⊕ dilate_k[k], ∩ target, on packed rows (see module docstring).

    ``check(band_words)`` is called before the per-angle words are allocated.
    """
    ny, nw = inp.shape
    last = _last_mask(nx)
    n = erode_k.shape[0]
    er = [_to_runs(_mask_runs(m, radius), dilate=False, order_from_centre=False) for m in erode_k]
    di = [_to_runs(_mask_runs(m, radius), dilate=True, order_from_centre=True) for m in dilate_k]
    union_runs = _to_runs(_mask_runs(erode_k.any(axis=0), radius), dilate=False,
                          order_from_centre=False)
    common_runs = _to_runs(_mask_runs(erode_k.all(axis=0), radius), dilate=False,
                           order_from_centre=False)
    reach_runs = _to_runs(_mask_runs(dilate_k.any(axis=0), radius), dilate=True,
                          order_from_centre=True)
    pr, pw = _k.table_padding(radius)
    lev_e = 1 + max([r.max_level for r in er] + [union_runs.max_level])
    t_and = np.zeros((lev_e, ny + 2 * pr, nw + 2 * pw), np.uint64)
    _k.build_tables(inp, t_and, pr, pw, True, 0, ny)
    fa = t_and.reshape(-1)
    nwp = t_and.shape[2]

    def flat(r: _Runs, table: np.ndarray) -> np.ndarray:
        return _k.flat_runs(r.table, table.shape, pr, pw)

    all_i = np.repeat(np.arange(ny, dtype=np.int64), nw)
    all_w = np.tile(np.arange(nw, dtype=np.int64), ny)
    empty = np.zeros(0, np.uint64)
    # deep: held at every angle (erosion by the union of the kernels); maybe: may be held at
    # some angle (erosion by their intersection); only the words between are computed per angle
    deep = np.empty((ny, nw), np.uint64)
    _k.erode_words(fa, nwp, flat(union_runs, t_and), all_i, all_w, last, deep, empty)
    maybe = np.empty((ny, nw), np.uint64)
    _k.erode_words(fa, nwp, flat(common_runs, t_and), all_i, all_w, last, maybe, empty)
    del all_i, all_w
    # pixels no angle can reach are dropped from the dilation target, so that words whose
    # remaining pixels are out of reach are not recomputed at every angle
    lev_d = 1 + max([r.max_level for r in di] + [reach_runs.max_level])
    t_or = np.zeros((lev_d, ny + 2 * pr, nw + 2 * pw), np.uint64)
    _k.build_tables(maybe, t_or, pr, pw, False, 0, ny)
    reach = np.zeros((ny, nw), np.uint64)
    fo = t_or.reshape(-1)
    _k.dilate_words(fo, nwp, flat(reach_runs, t_or), target, reach)
    band = np.flatnonzero((maybe & ~deep).reshape(-1))
    del maybe
    band_i = (band // nw).astype(np.int64)
    band_w = (band % nw).astype(np.int64)
    if check is not None:
        check(len(band))
    values = np.empty((n if store else 0, len(band)), np.uint64)
    work = deep.copy()
    _k.build_tables(work, t_or, pr, pw, False, 0, ny)
    union = np.zeros((ny, nw), np.uint64)
    # a dilation of output word (i, w) reads P rows i ± radius and words w ± rw
    rw = radius // 64 + 3
    for k in range(n):
        if store:
            sel_i, sel_w = band_i, band_w
            _k.erode_words(fa, nwp, flat(er[k], t_and), sel_i, sel_w, last, work, values[k])
        else:
            # only P words a dilation can still read need to be right: those near words
            # with target pixels not yet covered (stale words elsewhere are never read)
            sel = _k.near_needy(reach, union, band_i, band_w, radius, rw)
            sel_i, sel_w = band_i[sel], band_w[sel]
            _k.erode_words(fa, nwp, flat(er[k], t_and), sel_i, sel_w, last, work, empty)
        if len(di[k].table):
            _k.update_tables(work, t_or, pr, pw, sel_i, sel_w, False)
            _k.dilate_words(fo, nwp, flat(di[k], t_or), reach, union)
        tick()
    return _PassResult(union, deep, band_i, band_w, values)


# --------------------------------------------------------------------------- vectorising


def _bits_to_geometry(bits: np.ndarray, grid: Grid) -> BaseGeometry:
    """The pixel set of a packed mask as shapely geometry, exactly (pixel edges).

    The boundary (axis-parallel, noded segments) is polygonized; the faces
    whose interior point falls on a set pixel are kept. Faces touch at most
    at corners, so their MultiPolygon is valid. Cost O(ny·nx/64 + boundary).
    """
    seg = _k.boundary_segments(bits, grid.nx)
    if len(seg) == 0:
        return MultiPolygon()
    ends = np.stack([seg[:, :2], seg[:, 2:]], axis=1) * grid.h + np.array([grid.x0, grid.y0])
    # merging the segments into chains first makes polygonize several times faster
    chains = shapely.line_merge(shapely.multilinestrings(shapely.linestrings(ends)))
    faces = shapely.get_parts(shapely.polygonize(shapely.get_parts(chains)))
    if len(faces) == 0:
        return MultiPolygon()
    xy = shapely.get_coordinates(shapely.point_on_surface(faces))
    i = np.clip(np.floor((xy[:, 1] - grid.y0) / grid.h).astype(np.int64), 0, grid.ny - 1)
    j = np.clip(np.floor((xy[:, 0] - grid.x0) / grid.h).astype(np.int64), 0, grid.nx - 1)
    on = (bits[i, j >> 6] >> (j & 63).astype(np.uint64)) & np.uint64(1)
    return MultiPolygon(list(faces[on.astype(bool)]))


def _runs_to_geometry(rr: np.ndarray, rs: np.ndarray, re: np.ndarray, grid: Grid
                      ) -> BaseGeometry:
    """Union of pixel runs as shapely geometry, via a cropped mask."""
    if len(rr) == 0:
        return MultiPolygon()
    r0, r1 = int(rr.min()), int(rr.max()) + 1
    c0, c1 = int(rs.min()), int(re.max())
    mask = np.zeros((r1 - r0, c1 - c0), bool)
    for r, a, b in zip((rr - r0).tolist(), (rs - c0).tolist(), (re - c0).tolist(), strict=True):
        mask[r, a:b] = True
    sub = Grid(grid.x0 + c0 * grid.h, grid.y0 + r0 * grid.h, grid.h, c1 - c0, r1 - r0)
    return _bits_to_geometry(_k.pack_bits(mask), sub)


# --------------------------------------------------------------------------- components


def _components(packed: PackedMasks, angles: np.ndarray, wrap: bool, grid: Grid
                ) -> tuple[Components, list[str]]:
    """Components of P over angles: run labelling per angle, overlaps of consecutive angles."""
    n = len(packed)
    runs = []
    labels = []
    counts = []
    total = 0
    for k in range(n):
        rr, rs, re = _k.extract_runs(packed.bits(k), grid.nx)
        lab, cnt = _k.label_runs(rr, rs, re)
        runs.append((rr, rs, re))
        labels.append(lab)
        counts.append(int(cnt))
        total += len(rr)
    pairs: dict[tuple[int, int], set[tuple[int, int]]] = {}
    steps = [(k, k + 1) for k in range(n - 1)]
    if wrap and n > 2:
        steps.append((n - 1, 0))
    for k, k2 in steps:
        a, b = runs[k], runs[k2]
        pr = _k.overlap_pairs(a[0], a[1], a[2], labels[k], b[0], b[1], b[2], labels[k2])
        code = np.unique(pr[:, 0] * (1 << 32) + pr[:, 1])
        pairs[(k, k2)] = set(zip((code >> 32).tolist(), (code & 0xFFFFFFFF).tolist(),
                                 strict=True))
    pieces = [list(range(c)) for c in counts]
    comp = component_labels(
        pieces, lambda k, a, k2, b: (a, b) in pairs.get((k, k2), ()), wrap=wrap and n > 2)
    n_comp = 1 + max((max(row) for row in comp if row), default=-1)
    ranges = tuple(angle_ranges(comp, angles)) if n_comp else ()
    notes = []
    geoms: tuple[BaseGeometry, ...] | None = None
    if total <= _COMPONENT_RUNS:
        per: list[list[np.ndarray]] = [[] for _ in range(n_comp)]
        for k in range(n):
            rr, rs, re = runs[k]
            cid = np.asarray(comp[k], np.int64)[labels[k]] if counts[k] else np.zeros(0, int)
            for c in np.unique(cid):
                sel = cid == c
                per[c].append(np.column_stack([rr[sel], rs[sel], re[sel]]))
        out = []
        for c in range(n_comp):
            allr = np.concatenate(per[c])
            out.append(_runs_to_geometry(*_merge_runs(allr), grid))
        geoms = tuple(out)
    else:
        notes.append(f"component geometries not vectorised ({total:,} runs over the angles)")
    return Components(count=n_comp, geometries=geoms, angle_ranges=ranges), notes


def _merge_runs(r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Union of runs (row, start, stop) per row: disjoint, sorted runs."""
    r = r.astype(np.int64)
    order = np.lexsort((r[:, 1], r[:, 0]))
    rows, st, en = r[order, 0], r[order, 1], r[order, 2]
    if len(rows) == 0:
        return rows, st, en
    span = int(en.max()) + 1
    # running max of the stop within each row (rows ascend, so row·span + stop ascends too)
    reach = np.maximum.accumulate(rows * span + en)
    new = np.ones(len(rows), bool)
    new[1:] = (rows[1:] != rows[:-1]) | (st[1:] > reach[:-1] - rows[1:] * span)
    first = np.flatnonzero(new)
    return rows[first], st[first], np.maximum.reduceat(en, first)


# --------------------------------------------------------------------------- progress


@contextmanager
def _progress(enabled: bool, total: int) -> Iterator[Callable[[], None]]:
    if not enabled:
        yield lambda: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn

    with Progress("raster MMC", BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  transient=True) as bar:
        task = bar.add_task("angles", total=total)
        yield lambda: bar.advance(task)


def _erode3(mask: np.ndarray) -> np.ndarray:
    """Erosion by the 3×3 box (outside the array counts as False)."""
    p = np.zeros((mask.shape[0] + 2, mask.shape[1] + 2), bool)
    p[1:-1, 1:-1] = mask
    out = mask.copy()
    for di in (0, 1, 2):
        for dj in (0, 1, 2):
            out &= p[di:di + mask.shape[0], dj:dj + mask.shape[1]]
    return out


def _popcount(bits: np.ndarray) -> int:
    if hasattr(np, "bitwise_count"):
        return int(np.bitwise_count(bits).sum(dtype=np.int64))
    return int(_k.unpack_bits(bits, bits.shape[-1] * 64).sum())


# --------------------------------------------------------------------------- engine


def mmc_raster(region: MultiPolygon, nozzle: Nozzle, machine: Machine, *,
               settings: Settings = DEFAULT_SETTINGS) -> MMCResult:
    """MMC of one layer on a separable machine by bit-parallel raster morphology.

    Parameters
    ----------
    region
        The layer target G (validated with :func:`as_region`).
    nozzle, machine
        The nozzle and a separable machine (``xy`` or ``ttr``).
    settings
        ``resolution`` (grid spacing h, mm), ``angle_step`` (degrees; None =
        the machine's), ``quad_segs``, ``max_memory``, ``progress``.

    Returns
    -------
    MMCResult
        ``motion.packed`` holds the inner P per angle (every position in it
        keeps the whole nozzle inside G), ``motion.count`` how many sampled
        angles fit at each pixel, ``as_built_raster`` S_inner (``as_built``
        its vectorised outline when affordable, else None), ``lost_area`` the
        centre-sampled estimate and ``lost_area_bounds`` the proven [lo, hi].

    Raises
    ------
    InputError
        A non-separable machine, or a region that is not a valid polygonal area.
    ResourceError
        Before allocation, when the estimated memory exceeds ``settings.max_memory``.

    Notes
    -----
    Approximation: hi − lo is O(perimeter · (h + δ)) with δ = ρ·Δ/2 (see the
    module docstring for the proof); in practice hi − estimate ≈ 1.5–2 h per
    mm of perimeter (the inner result gives up the cut pixels and the ring
    of inside pixels next to them), lo is much closer. ``motion.masks`` (a
    boolean stack) is also filled when it is at most 64 MiB. Components are
    labelled on the runs of each P_φ (the same 4-connected partition as
    ``scipy.ndimage.label``, without unpacking 180 images) and linked across
    consecutive angles by :func:`~printability.mmc.components.component_labels`;
    their geometry is vectorised when the runs are few. Cost O(nx·ny) for the raster and, per
    angle, O(band words × kernel rows) with the band O(perimeter × nozzle
    size / 64) words; memory ≈ 24 bytes per pixel plus 8 bytes per band word
    and angle.
    """
    t_start = time.perf_counter()
    if not machine.separable:
        raise InputError(f"the raster engine needs a separable machine (xy or ttr); machine "
                         f"{machine.name!r} is a joint chain: use the sampled engine")
    g = as_region(region)
    prob = prepare_raster(g, nozzle, machine, settings=settings)
    grid = prob.grid
    n = len(prob.angles)
    cls = prob.cls
    inside = _k.pack_bits(cls == 3)
    notes = [
        f"raster h = {grid.h:g} mm on {grid.nx} × {grid.ny} pixels, {n} angle(s)"
        + (f" (gap {prob.angle_gap:g}°, angular margin δ = {prob.delta:.4g} mm)" if n > 1 else ""),
    ]
    if not prob.full.any(axis=(1, 2)).all():
        notes.append("at some angles no pixel lies wholly inside the nozzle: the inner result "
                     "there is empty; use a finer resolution")

    with _progress(settings.progress, 3 * n) as tick:
        # a pixel wholly inside a closed footprint makes it touch its 8 neighbours, which
        # must then be inside pixels: S_inner ⊆ I ⊖ (3×3 box)
        core = _k.pack_bits(_erode3(cls == 3))
        inner = _opening_pass(
            inside, core, prob.touch, prob.full, prob.radius, grid.nx, store=True, tick=tick,
            check=lambda words: _check_memory(
                estimate_memory(grid, n, prob.radius, band_words=words), settings,
                f"the motion restriction at {n} angles ({words:,} words vary with the angle)"))
        del core
        some = _k.pack_bits(cls >= 1)
        outer = _opening_pass(some, some, prob.need, prob.dil, prob.radius, grid.nx,
                              store=False, tick=tick)
        centre_in = _k.pack_bits(cls >= 2)
        est = _opening_pass(centre_in, centre_in, prob.centre, prob.centre, prob.radius,
                            grid.nx, store=False, tick=tick)
        del some, centre_in

    h2 = grid.pixel_area
    target_area = float(g.area)
    s_inner = _k.unpack_bits(inner.union, grid.nx)
    inner_area = float(np.count_nonzero(s_inner)) * h2
    outer_mask = _k.unpack_bits(outer.union, grid.nx)
    outer_area = float(prob.cov[outer_mask].sum()) * h2
    del outer_mask
    tol = 1e-9 * target_area
    lo = max(0.0, target_area - outer_area - tol)
    hi = min(target_area, target_area - inner_area + tol)
    # both areas on the same centre-sampled raster, so the sampling of ∂G cancels out
    lost_est = (int(np.count_nonzero(cls >= 2)) - _popcount(est.union)) * h2
    lost = min(max(lost_est, lo), hi)

    flat_words = (inner.band_i * inner.base.shape[1] + inner.band_w).astype(np.int64)
    packed = PackedMasks(grid, inner.base, flat_words, inner.values)
    count = np.zeros(grid.shape, np.uint16)
    _k.count_bits_into(count, inner.base, inner.band_i, inner.band_w, inner.values, n)
    masks = None
    if n * grid.nx * grid.ny <= _MASKS_LIMIT:
        masks = Raster(grid, np.stack([packed.mask(k).data for k in range(n)]))
    motion = MotionRestriction(angles=prob.angles.copy(), masks=masks,
                               count=Raster(grid, count), packed=packed)
    components, cnotes = _components(packed, prob.angles, prob.wrap, grid)
    notes.extend(cnotes)

    rr, _, _ = _k.extract_runs(inner.union, grid.nx)
    as_built = None
    if len(rr) <= _VECTOR_RUNS:
        as_built = _bits_to_geometry(inner.union, grid)
    else:
        notes.append(f"as-built geometry not vectorised ({len(rr):,} pixel runs); "
                     "see as_built_raster")
    return MMCResult(
        engine="raster",
        nozzle=nozzle,
        machine=machine,
        target=g,
        as_built=as_built,
        target_area=target_area,
        as_built_area=target_area - lost,
        lost_area=lost,
        lost_area_bounds=(lo, hi),
        motion=motion,
        components=components,
        resolution=grid.h,
        angle_step=prob.angle_gap,
        elapsed=time.perf_counter() - t_start,
        as_built_raster=Raster(grid, s_inner),
        notes=tuple(notes),
        extra={"inner_as_built_area": inner_area, "outer_as_built_area": outer_area,
               "estimate_lost_area": lost_est, "band_words": len(inner.band_i),
               "grid": grid, "angular_margin": prob.delta},
    )

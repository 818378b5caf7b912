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
Pixels are the closed squares Q_ij of the Grid (see :mod:`printability.model.geometry`
for the axis order), c_ij their centres. A kernel offset d = (di, dj) is the
pixel Q'_d = [(dj−½)h, (dj+½)h] × [(di−½)h, (di+½)h] about the nozzle origin;
placing a set at c_ij moves Q'_d onto Q_{(i,j)+d}. Erosion is without
reflection, ``(X ⊖ K)(c) = ∧_{d∈K} X(c + d)``, and dilation
``(P ⊕ K)(s) = ∨_{d∈K} P(s − d)``, as in the geometry module.

Conservative rasterisation of G
    Every pixel is *inside* (I), *outside* or *cut* (C), with its exact
    covered fraction cov = λ(Q ∩ G)/h²: Q ⊆ int G for an inside pixel, Q ∩ G
    = ∅ for an outside one, and C holds every pixel ∂G meets
    (:mod:`printability.mmc._raster_prepare`, which proves it).

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
    The ±δ buffers that make core_k and F_k ⊕ D(δ) are inflated so that
    GEOS's chords cannot cross the true arcs (see
    :mod:`printability.mmc._raster_prepare`).

Estimate
    The centre-sampled opening: B = pixels whose centre is in G, K_c(k) =
    offsets whose centre is in the footprint, S_est = ∪_k (B ⊖ K_c) ⊕ K_c;
    lost = h²·|B \\ S_est| (both sides sampled alike, so the sampling of ∂G
    cancels), clipped into [lo, hi]. It converges to the
    sampled-angle value as h → 0 (O(h) near ∂G, usually much better).

Band settling (nozzles of one circle or ellipse)
    The uncertainty left is a band: the pixels cut by ∂G and those where the
    inner and outer passes disagree. :mod:`printability.mmc._band` settles them
    below the pixel with exact geometry: certified slides of the footprint
    along every edge (segments of P) and their end disks give a certified part
    of S; a quadtree over each uncertain pixel counts what they do not cover
    (a new, much smaller ``hi``), proves lost the leaves a convex chain of edges
    keeps every footprint away from (a larger ``lo``), and estimates the loss
    from the pieces of every sampled angle. The engine keeps, for each end of
    the interval, the tighter of the two certified values. Cost grows with the
    boundary's length over h (the band), not the area over h².

Floating point: lo and hi are widened by 1e-9·λ(G) to absorb the rounding
of the classification and the coverage sums (bounded in
:mod:`printability.mmc._raster_prepare`).

Speed
    Masks are bit-packed, 64 pixels per ``uint64`` word, and each pass
    computes only the words where P can change with the angle; how, what it
    costs and why it stays exact: :mod:`printability.mmc._raster_passes`.
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

from printability.errors import InputError
from printability.mmc._raster_kernels import count_bits_into, pack_bits, unpack_bits
from printability.mmc._raster_passes import PassResult, opening_pass
from printability.mmc._raster_prepare import (
    RasterProblem,
    check_memory,
    estimate_memory,
    prepare_raster,
    rasterize_region,
)
from printability.mmc._raster_runs import (
    boundary_segments,
    extract_runs,
    label_runs,
    overlap_pairs,
)
from printability.mmc.components import angle_ranges, component_labels
from printability.mmc.result import (
    Components,
    MMCInternalError,
    MMCResult,
    MotionRestriction,
    PackedMasks,
)
from printability.model.geometry import Grid, Raster, as_region
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle
from printability.settings import DEFAULT_SETTINGS, Settings

__all__ = [
    "RasterProblem",
    "estimate_memory",
    "mmc_raster",
    "prepare_raster",
    "rasterize_region",
]

# booleans (n_angles·ny·nx bytes) up to which MotionRestriction.masks is filled too
_MASKS_LIMIT = 64 << 20
# runs up to which S_inner and the components are vectorised to shapely geometry
_VECTOR_RUNS = 400_000
_COMPONENT_RUNS = 400_000


# --------------------------------------------------------------------------- vectorising


def _bits_to_geometry(bits: np.ndarray, grid: Grid) -> BaseGeometry:
    """The pixel set of a packed mask as shapely geometry, exactly (pixel edges).

    The boundary (axis-parallel, noded segments) is polygonized; the faces
    whose interior point falls on a set pixel are kept. Faces touch at most
    at corners, so their MultiPolygon is valid. Cost O(ny·nx/64 + boundary).
    """
    seg = boundary_segments(bits, grid.nx)
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
    return _bits_to_geometry(pack_bits(mask), sub)


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
        rr, rs, re = extract_runs(packed.bits(k), grid.nx)
        lab, cnt = label_runs(rr, rs, re)
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
        pr = overlap_pairs(a[0], a[1], a[2], labels[k], b[0], b[1], b[2], labels[k2])
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
    return int(unpack_bits(bits, bits.shape[-1] * 64).sum())


# --------------------------------------------------------------------------- band


#: Leaves of the band's quadtree go down to h / 2**BAND_LEVELS.
BAND_LEVELS = 6


def band_settles(nozzle: Nozzle) -> bool:
    """Whether :mod:`printability.mmc._band` applies: one circle or ellipse orifice."""
    return len(nozzle.footprints) == 1 and nozzle.footprints[0].conic


def _settle_band(g: MultiPolygon, nozzle: Nozzle, prob: RasterProblem, s_inner: np.ndarray,
                 outer_mask: np.ndarray) -> dict:
    """Certified bounds and estimate over the uncertain pixels (:mod:`._band`)."""
    from printability.mmc._band import (
        BandBoundary,
        BandFootprint,
        BandRaster,
        edges_of,
        neighbour_pairs,
        settle_band,
    )
    from printability.mmc._raster_prepare import oriented_rings
    from printability.model.geometry import rotation_matrix

    f = nozzle.footprints[0]
    # the same set with the longer semi-axis first (a turn by 90° swaps them)
    a, b, rot = (f.a, f.b, f.rotation) if f.a >= f.b else (f.b, f.a, f.rotation + 90.0)
    totals = [nozzle.mount_angle + float(phi) + rot for phi in prob.angles]
    lmats = [rotation_matrix(t) @ np.diag([a, b]) for t in totals]
    half = math.radians(prob.angle_gap) / 2.0 if len(prob.angles) > 1 else 0.0
    cells = np.array([[*np.linalg.inv(m).ravel(), math.radians(t), half]
                      for m, t in zip(lmats, totals, strict=True)])
    edges, prev_, next_ = edges_of(*oriented_rings(g))
    scale = 1.0 + float(np.abs(edges).max()) if len(edges) else 1.0
    ptr, idx = neighbour_pairs(edges, 2.02 * a + 1e-9 * scale)
    uncertain = (prob.cov > 0.0) & ~s_inner
    # the support function of an ellipse turns by at most (a − b) per radian (_band)
    delta = (a - b) * half * (1.0 + 1e-9)
    out = settle_band(
        g, BandRaster(prob.grid, prob.cls, prob.cov, uncertain, outer_mask),
        BandBoundary(edges, prev_, next_, ptr, idx),
        BandFootprint(lmats, cells, a, b, delta), max_level=BAND_LEVELS)
    out.update(pixels=int(np.count_nonzero(uncertain)), max_level=BAND_LEVELS)
    return out


# --------------------------------------------------------------------------- engine


def mmc_raster(region: MultiPolygon, nozzle: Nozzle, machine: Machine, *,
               settings: Settings = DEFAULT_SETTINGS, settle_band: bool = True) -> MMCResult:
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
    settle_band
        For a nozzle of one circle or ellipse, settle the uncertain pixels below the
        pixel with exact slides (:mod:`printability.mmc._band`): a much tighter
        upper bound and estimate. False gives the plain raster result.

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
    Approximation: without the band settling, hi − lo is O(perimeter · (h + δ))
    with δ = ρ·Δ/2 (see the module docstring for the proof); in practice
    hi − estimate ≈ 1.5–2 h per mm of perimeter (the inner result gives up the
    cut pixels and the ring of inside pixels next to them). With it (one circle
    or ellipse), hi is within the quadtree's last leaves (h/64) of the sampled
    loss, lo within δ' = (a − b)·Δ/2 at corners and convex tips (elsewhere the
    outer pass's ≈ 4h per mm of the lost parts' boundary), and the estimate
    within about 1 % (``benchmarks/bench_bounds.py``). ``motion.masks`` (a
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
    notes = _grid_notes(prob)
    passes = _opening_passes(prob, settings)
    bounds = _lost_bounds(g, nozzle, prob, passes, settle_band=settle_band)
    notes.extend(bounds.notes)
    inner = passes.inner
    motion = _motion_restriction(prob, inner)
    components, cnotes = _components(motion.packed, prob.angles, prob.wrap, grid)
    notes.extend(cnotes)
    as_built, anotes = _as_built(inner.union, grid)
    notes.extend(anotes)
    target_area = bounds.target_area
    return MMCResult(
        engine="raster",
        nozzle=nozzle,
        machine=machine,
        target=g,
        as_built=as_built,
        target_area=target_area,
        as_built_area=target_area - bounds.lost,
        lost_area=bounds.lost,
        lost_area_bounds=(bounds.lo, bounds.hi),
        motion=motion,
        components=components,
        resolution=grid.h,
        angle_step=prob.angle_gap,
        elapsed=time.perf_counter() - t_start,
        as_built_raster=Raster(grid, bounds.s_inner),
        notes=tuple(notes),
        extra={"inner_as_built_area": bounds.inner_area,
               "outer_as_built_area": bounds.outer_area,
               "estimate_lost_area": bounds.lost_est, "band_words": len(inner.band_i),
               "grid": grid, "angular_margin": prob.delta,
               **({"band": bounds.settled} if bounds.settled is not None else {})},
    )


# --------------------------------------------------------------------------- stages


def _grid_notes(prob: RasterProblem) -> list[str]:
    """The notes on the grid and the angles (and on kernels too coarse to fill a pixel)."""
    grid = prob.grid
    n = len(prob.angles)
    notes = [
        f"raster h = {grid.h:g} mm on {grid.nx} × {grid.ny} pixels, {n} angle(s)"
        + (f" (gap {prob.angle_gap:g}°, angular margin δ = {prob.delta:.4g} mm)" if n > 1 else ""),
    ]
    if not prob.full.any(axis=(1, 2)).all():
        notes.append("at some angles no pixel lies wholly inside the nozzle: the inner result "
                     "there is empty; use a finer resolution")
    return notes


@dataclass(frozen=True, eq=False)
class _Passes:
    """The three opening passes: inner (stores P per angle), outer and estimate."""

    inner: PassResult
    outer: PassResult
    est: PassResult


def _opening_passes(prob: RasterProblem, settings: Settings) -> _Passes:
    """The inner, outer and estimate openings of the module docstring, on packed rows."""
    grid = prob.grid
    n = len(prob.angles)
    cls = prob.cls
    inside = pack_bits(cls == 3)
    with _progress(settings.progress, 3 * n) as tick:
        # a pixel wholly inside a closed footprint makes it touch its 8 neighbours, which
        # must then be inside pixels: S_inner ⊆ I ⊖ (3×3 box)
        core = pack_bits(_erode3(cls == 3))
        inner = opening_pass(
            inside, core, prob.touch, prob.full, prob.radius, grid.nx, store=True, tick=tick,
            check=lambda words: check_memory(
                estimate_memory(grid, n, prob.radius, band_words=words), settings,
                f"the motion restriction at {n} angles ({words:,} words vary with the angle)"))
        del core
        some = pack_bits(cls >= 1)
        outer = opening_pass(some, some, prob.need, prob.dil, prob.radius, grid.nx,
                             store=False, tick=tick)
        centre_in = pack_bits(cls >= 2)
        est = opening_pass(centre_in, centre_in, prob.centre, prob.centre, prob.radius,
                           grid.nx, store=False, tick=tick)
        del some, centre_in
    return _Passes(inner, outer, est)


@dataclass(frozen=True, eq=False)
class _Bounds:
    """The lost area: its estimate, certified bounds and what they were made from."""

    target_area: float
    lo: float
    hi: float
    lost: float              # the estimate clipped into [lo, hi]
    lost_est: float          # the estimate before clipping
    inner_area: float
    outer_area: float
    s_inner: np.ndarray      # boolean S_inner
    settled: dict | None     # the band settling's figures, when it ran
    notes: list[str]


def _lost_bounds(g: MultiPolygon, nozzle: Nozzle, prob: RasterProblem, passes: _Passes, *,
                 settle_band: bool) -> _Bounds:
    """lo, hi and the estimate from the passes, tightened by the band settling when it
    applies (each pair is certified: the tighter end of each side is kept)."""
    grid = prob.grid
    h2 = grid.pixel_area
    target_area = float(g.area)
    s_inner = unpack_bits(passes.inner.union, grid.nx)
    inner_area = float(np.count_nonzero(s_inner)) * h2
    outer_mask = unpack_bits(passes.outer.union, grid.nx)
    outer_area = float(prob.cov[outer_mask].sum()) * h2
    tol = 1e-9 * target_area
    lo = max(0.0, target_area - outer_area - tol)
    hi = min(target_area, target_area - inner_area + tol)
    # both areas on the same centre-sampled raster, so the sampling of ∂G cancels out
    lost_est = (int(np.count_nonzero(prob.cls >= 2)) - _popcount(passes.est.union)) * h2
    settled = None
    notes = []
    if settle_band and band_settles(nozzle):
        settled = _settle_band(g, nozzle, prob, s_inner, outer_mask)
        hi = min(hi, min(target_area, settled["upper"] + tol))
        lo = max(lo, settled["lower"] - tol)
        if lo > hi:
            raise MMCInternalError(
                f"raster engine: the band settling bounds the lost area by [{lo!r}, {hi!r}] "
                "mm², an empty interval. This is a bug: please report it with the input.")
        lost_est = settled["estimate"]
        notes.append(
            f"band settled below the pixel: {settled['pixels']:,} uncertain pixels, "
            f"{settled['pieces']:,} certified slides and caps, leaves down to "
            f"{grid.h / 2 ** settled['max_level']:.3g} mm ({settled['undecided']:.3g} mm² "
            "undecided)")
    del outer_mask
    lost = min(max(lost_est, lo), hi)
    return _Bounds(target_area, lo, hi, lost, lost_est, inner_area, outer_area, s_inner,
                   settled, notes)


def _motion_restriction(prob: RasterProblem, inner: PassResult) -> MotionRestriction:
    """P per angle (packed; also as booleans when small), and how many angles fit per pixel."""
    grid = prob.grid
    n = len(prob.angles)
    flat_words = (inner.band_i * inner.base.shape[1] + inner.band_w).astype(np.int64)
    packed = PackedMasks(grid, inner.base, flat_words, inner.values)
    count = np.zeros(grid.shape, np.uint16)
    count_bits_into(count, inner.base, inner.band_i, inner.band_w, inner.values, n)
    masks = None
    if n * grid.nx * grid.ny <= _MASKS_LIMIT:
        masks = Raster(grid, np.stack([packed.mask(k).data for k in range(n)]))
    return MotionRestriction(angles=prob.angles.copy(), masks=masks,
                             count=Raster(grid, count), packed=packed)


def _as_built(union: np.ndarray, grid: Grid) -> tuple[BaseGeometry | None, list[str]]:
    """S_inner as geometry when its runs are few enough (else None and a note)."""
    rr, _, _ = extract_runs(union, grid.nx)
    if len(rr) <= _VECTOR_RUNS:
        return _bits_to_geometry(union, grid), []
    return None, [f"as-built geometry not vectorised ({len(rr):,} pixel runs); "
                  "see as_built_raster"]

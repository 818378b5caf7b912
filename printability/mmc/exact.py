"""The exact (vector) MMC engine: P and S as shapely polygons, with certified bounds.

For a separable machine (XY, T-T-R) the nozzle at angle φ is the footprint
A_φ = R(φ)·A⁰ and (docs/design.md §2, conventions in :mod:`printability.model.geometry`)

    P_φ = {t : A_φ + t ⊆ G} = G ⊖ A_φ,      S = ∪_φ (P_φ ⊕ A_φ).

Three footprint families are handled without rasterising anything.

Circles and ellipses (the affine trick)
    An elliptical orifice is A = c + L·D with D the unit disk, c its centre
    and L = R(φ + ρ)·diag(a, b) (a circle is a = b). Since L is invertible,
    A + t ⊆ G ⟺ D + L⁻¹(t + c) ⊆ L⁻¹G, so P = L·(L⁻¹G ⊖ D) − c and
    P ⊕ A = L·(L⁻¹(P + c) ⊕ D): one inward and one outward offset of a unit
    disk in the mapped plane (:func:`shapely.affinity.affine_transform`),
    then mapped back with the certified offsets of
    :mod:`printability.mmc._disk_offsets`. Affine maps preserve inclusions,
    so every containment proved there in the mapped plane holds after mapping
    back.
Rectangles and polygons (Minkowski operations)
    For a path-connected footprint K, P and P ⊕ K are unions and differences
    of convex hulls of the boundary segments and K's convex pieces: no
    approximation beyond floating point (proof and MMC check in
    :mod:`printability.mmc._minkowski`).
Heads with several orifices
    Every orifice must stay inside G: P = ∩_j P_j (each orifice's own P) and
    S = ∪_j (P ⊕ A_j).

Why the result is safe (MMC) and how the bounds are certified
-------------------------------------------------------------
For a disk of radius r, :mod:`printability.mmc._disk_offsets` proves (and,
for P_inner, verifies) P_inner ⊆ P ⊆ P_outer and S_inner ⊆ P_inner ⊕ D_r ⊆ S
⊆ S_outer, stating the GEOS behaviour the bands rely on; P_inner is the set
the engine reports as P. For polygons the Minkowski operations are exact up
to rounding and their P is checked with exact predicates.

Hence λ(G \\ S_outer) ≤ λ(G \\ S) ≤ λ(G \\ S_inner): the reported
``lost_area_bounds`` contain the exact lost area of the sampled angles, and
differ from it only by slivers within r·(1/κ − 1) of arcs (≈ 10⁻³ of the
lost area on the rectangle test; κ from :func:`chord_factor`).

T-T-R between samples. Turning by |Δ| ≤ Δφ/2 (half the largest gap between
consecutive sampled angles, wrapping over the symmetry period) moves no
nozzle point by more than δ = ρ·Δφ/2 (ρ = ``nozzle.radius``, Δφ in radians),
so A_k ⊖ D_δ ⊆ A_φ ⊆ A_k ⊕ D_δ for the nearest sample φ_k. Then
P_φ ⊆ G ⊖ (A_k ⊖ D_δ) and S_φ ⊆ (G ⊖ K⁻) ⊕ K⁺ for any K⁻ ⊆ A_k ⊖ D_δ and
K⁺ ⊇ A_k ⊕ D_δ. For an ellipse (semi-minor b) K^∓ = c + (1 ∓ δ/b)(A_k − c),
because D_δ ⊆ (δ/b)(A_k − c) and convexity gives sE ⊕ tE = (s + t)E; for a
polygon K⁻ is its verified erosion by δ and K⁺ the union over its convex
pieces K_i of hull(K_i ⊕ a polygon containing D_δ). So the lower bound also
holds for the continuous rotary range, whose exact lost area can only be
smaller than the sampled one (more angles print more).

Complexity
----------
Per angle and orifice: the disk offsets of
:mod:`printability.mmc._disk_offsets` (O(n) one-sided pieces and their union
for n boundary vertices, the dominant cost) or the convex hulls of
:mod:`printability.mmc._minkowski` (O(n·m)), whose docstrings give the
details; linear in the number of sampled angles.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely
import shapely.affinity
from shapely.geometry import MultiPolygon, Point, Polygon
from shapely.geometry.base import BaseGeometry
from shapely.ops import polylabel

from printability.errors import InputError
from printability.mmc._disk_offsets import (
    certified_erosion,
    chord_factor,
    dilate_disk,
    disk_cover,
    erode_disk,
)
from printability.mmc._minkowski import (
    convex_pieces,
    largest_polygon,
    minkowski_dilate,
    minkowski_erode,
)
from printability.mmc._offset_bands import EMPTY, as_multi
from printability.mmc.components import angle_ranges, component_labels
from printability.mmc.result import Components, MMCInternalError, MMCResult, MotionRestriction
from printability.model.geometry import polygons_of, rotation_matrix
from printability.model.machine import Machine
from printability.model.nozzle import Footprint, Nozzle
from printability.settings import DEFAULT_SETTINGS, Settings

__all__ = [
    "angular_margin",
    "chord_factor",
    "dilate_disk",
    "erode_disk",
    "minkowski_dilate",
    "minkowski_erode",
    "mmc_exact",
    "sampled_angles",
]


# ------------------------------------------------------------------------- orifices


@dataclass(frozen=True)
class _Placed:
    """One orifice at one sampled angle, in the machine frame at the origin."""

    conic: bool  # c + L·D (circle, ellipse) rather than ``poly``
    c: tuple[float, float] = (0.0, 0.0)
    lmat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 1.0)  # row-major L
    b: float = 0.0  # semi-minor axis (conic), mm
    poly: Polygon | None = None


def _place(f: Footprint, total_angle: float) -> _Placed:
    rot = rotation_matrix(total_angle)
    if f.conic:
        c = rot @ np.asarray(f.center, float)
        lm = rotation_matrix(total_angle + f.rotation) @ np.diag([f.a, f.b])
        return _Placed(True, (float(c[0]), float(c[1])), tuple(float(x) for x in lm.ravel()),
                       b=min(f.a, f.b))
    poly = f.polygon(mode="inner")
    if total_angle % 360.0:
        poly = shapely.affinity.rotate(poly, total_angle, origin=(0.0, 0.0))
    return _Placed(False, poly=poly)


def _affine(m: np.ndarray, shift: np.ndarray | tuple[float, float] = (0.0, 0.0)) -> list[float]:
    return [m[0, 0], m[0, 1], m[1, 0], m[1, 1], float(shift[0]), float(shift[1])]


def _p_disk(g: BaseGeometry, o: _Placed, scale: float, quad_segs: int, outer: bool) -> MultiPolygon:
    """P for the orifice c + scale·L·D (affine trick)."""
    lm = scale * np.asarray(o.lmat).reshape(2, 2)
    inv = np.linalg.inv(lm)
    g1 = shapely.affinity.affine_transform(g, _affine(inv))
    p1 = erode_disk(g1, 1.0, quad_segs=quad_segs, outer=outer)
    # P = L·P' − c
    return as_multi(shapely.affinity.affine_transform(p1, _affine(lm, (-o.c[0], -o.c[1]))))


def _s_disk(p: BaseGeometry, o: _Placed, scale: float, quad_segs: int, outer: bool) -> MultiPolygon:
    """P ⊕ (c + scale·L·D) (affine trick)."""
    if p.is_empty:
        return EMPTY
    lm = scale * np.asarray(o.lmat).reshape(2, 2)
    inv = np.linalg.inv(lm)
    # L⁻¹(P + c)
    p1 = shapely.affinity.affine_transform(p, _affine(inv, inv @ np.asarray(o.c)))
    s1 = dilate_disk(p1, 1.0, quad_segs=quad_segs, outer=outer)
    return as_multi(shapely.affinity.affine_transform(s1, _affine(lm)))


@dataclass(frozen=True)
class _AngleResult:
    p_inner: MultiPolygon
    s_inner: MultiPolygon
    s_outer: MultiPolygon


def _one_angle(
    g: MultiPolygon, placed: Sequence[_Placed], delta: float, quad_segs: int
) -> _AngleResult:
    """P_inner, S_inner and S_outer (outer: covering angles within δ of this one)."""
    p_in: BaseGeometry | None = None
    p_out: BaseGeometry | None = None
    grown: list[tuple[_Placed, float, list[Polygon] | None]] = []
    whole_g = False
    for o in placed:
        if o.conic:
            pi = _p_disk(g, o, 1.0, quad_segs, outer=False)
            s_minus = 1.0 - delta / o.b
            if s_minus <= 0:
                whole_g = True  # K⁻ is empty: no upper bound on S from this orifice
                po = None
            else:
                po = _p_disk(g, o, s_minus, quad_segs, outer=True)
            grown.append((o, 1.0 + delta / o.b, None))
        else:
            k = o.poly
            pi = minkowski_erode(g, k)
            if delta > 0:
                k_minus = largest_polygon(certified_erosion(k, delta, quad_segs))
                # K_i ⊕ D_δ ⊆ hull(K_i's vertices + a polygon containing D_δ)
                ring = shapely.get_coordinates(shapely.buffer(
                    Point(0.0, 0.0), delta * disk_cover(quad_segs), quad_segs=quad_segs))
                pieces_plus = []
                for c in convex_pieces(k):
                    v = np.asarray(c.exterior.coords)[:-1]
                    sums = (v[:, None, :] + ring[None, :, :]).reshape(-1, 2)
                    pieces_plus.append(shapely.convex_hull(shapely.multipoints(sums)))
            else:
                k_minus, pieces_plus = k, convex_pieces(k)
            if k_minus is None:
                whole_g, po = True, None
            else:
                po = minkowski_erode(g, k_minus)
            grown.append((o, 1.0, pieces_plus))
        p_in = pi if p_in is None else p_in.intersection(pi)
        if po is not None:
            p_out = po if p_out is None else p_out.intersection(po)
    p_in = as_multi(p_in if p_in is not None else EMPTY)
    s_in_parts = []
    s_out_parts = []
    for o, s_plus, pieces_plus in grown:
        if o.conic:
            s_in_parts.append(_s_disk(p_in, o, 1.0, quad_segs, outer=False))
            if not whole_g and p_out is not None:
                s_out_parts.append(_s_disk(p_out, o, s_plus, quad_segs, outer=True))
        else:
            s_in_parts.append(minkowski_dilate(p_in, convex_pieces(o.poly)))
            if not whole_g and p_out is not None:
                s_out_parts.append(minkowski_dilate(p_out, pieces_plus or []))
    s_in = as_multi(shapely.union_all(s_in_parts)) if s_in_parts else EMPTY
    if whole_g:
        s_out = g
    elif p_out is None:
        s_out = EMPTY
    else:
        s_out = as_multi(shapely.union_all(s_out_parts)) if s_out_parts else EMPTY
    return _AngleResult(p_in, s_in, s_out)


# ------------------------------------------------------------------- self-check

#: P_inner must hold every point of G farther than this many reaches from ∂G.
_DEEP = 2.5


def _reach(o: _Placed) -> float:
    """Largest distance from the nozzle origin to a point of the placed orifice, mm."""
    if o.conic:
        # ‖L‖₂: the semi-major axis, whichever of a and b it is
        return math.hypot(*o.c) + float(np.linalg.norm(np.asarray(o.lmat).reshape(2, 2), 2))
    return float(np.max(np.hypot(*shapely.get_coordinates(o.poly).T)))


def _deep_points(g: MultiPolygon, reach: float) -> list[tuple[float, float, float]]:
    """Points (x, y, distance to ∂G) of G farther than :data:`_DEEP`·reach from ∂G.

    One per polygon of G that can hold such a disk (its pole of inaccessibility,
    :func:`shapely.ops.polylabel`, to 1 % of its size; the distance is measured
    exactly afterwards, so a coarse pole only makes the check skip a polygon).
    """
    need = _DEEP * reach
    out = []
    for q in g.geoms:
        minx, miny, maxx, maxy = q.bounds
        if min(maxx - minx, maxy - miny) <= 2 * need or q.area <= math.pi * need * need:
            continue
        c = polylabel(q, tolerance=max(0.01 * max(maxx - minx, maxy - miny), 0.1 * need))
        dist = float(q.exterior.distance(c))
        dist = min([dist] + [float(h.distance(c)) for h in q.interiors])
        if dist > need and q.contains(c):
            out.append((c.x, c.y, dist))
    return out


def _check_p_inner(
    g: MultiPolygon,
    p_inner: BaseGeometry,
    reach: float,
    pts: list[tuple[float, float, float]],
    phi: float,
) -> None:
    """Raise :class:`MMCInternalError` when P_inner misses a point where the nozzle fits.

    ``pts`` are G's deep points (:func:`_deep_points` for ``reach``). If t is
    farther than ρ (``reach``, the largest :func:`_reach` of the orifices) from ∂G,
    every orifice placed at t lies inside G, so t ∈ P. P_inner only ever
    removes points within 2·(1 + 10⁻⁷)·ρ of ∂G: the certified erosion's cuts
    (tangent triangles reach 2r from a vertex of ∂G, fans, disks and stadiums
    r/cos(π/(4·quad_segs))) and its global fallback (r/(κ − 1.05·10⁻³) ≤ 1.21·r
    for quad_segs ≥ 2) in the affine trick's mapped plane, where distances
    shrink by at most the semi-major axis; the Minkowski erosion removes only
    positions where the footprint meets ∂G. A point farther than 2.5·ρ from ∂G
    missing from P_inner is therefore a failure of the computation (issue #26:
    a triangle's P came out empty), not an approximation: refuse to report
    the nonsense result it would give (everything lost).
    """
    if not pts:
        return
    xy = np.asarray(pts)
    inside = shapely.contains_xy(p_inner, xy[:, 0], xy[:, 1]) if not p_inner.is_empty else \
        np.zeros(len(xy), bool)
    if inside.all():
        return
    x, y, dist = xy[np.flatnonzero(~inside)[0]]
    raise MMCInternalError(
        f"exact engine: the nozzle certainly fits at ({x:.6g}, {y:.6g}) (at angle {phi:g}°, "
        f"{dist:.4g} mm from the boundary, reach {reach:.4g} mm) but the computed motion "
        f"region P misses it (P area {p_inner.area:.6g} mm², part {g.area:.6g} mm²); the "
        "result would overstate the lost area. This is a bug: please report it with the "
        "input (try engine='raster' meanwhile)."
    )


# --------------------------------------------------------------------------- angles


def sampled_angles(
    nozzle: Nozzle, machine: Machine, settings: Settings
) -> tuple[np.ndarray, float, bool]:
    """The sampled angles, the largest gap Δφ between neighbours (degrees) and the wrap flag.

    A round nozzle, or an XY machine, has one angle and Δφ = 0 (nothing
    turns, or turning changes nothing). On a full turn (or a range covering
    the nozzle's symmetry period) the gap wraps from the last angle to the
    first plus the period.
    """
    period = nozzle.symmetry_period
    angles = np.asarray(machine.angles(step=settings.angle_step, period=period), dtype=float)
    if not machine.turns(nozzle) or len(angles) == 1:
        return angles[:1], 0.0, False
    span = machine.angle_max - machine.angle_min
    periodic = machine.full_turn or (0 < period < 360.0 and span >= period - 1e-9)
    gaps = list(np.diff(angles))
    if periodic:
        gaps.append(angles[0] + min(period, 360.0) - angles[-1])
    return angles, float(max(gaps)), periodic


def angular_margin(nozzle: Nozzle, gap_deg: float) -> float:
    """δ = ρ·Δφ/2: how far any nozzle point moves between a sample and the mid-gap, mm."""
    return nozzle.radius * math.radians(gap_deg) / 2.0


# ----------------------------------------------------------------------------- engine


def _progress(items: Sequence[float], enabled: bool, what: str):
    if not enabled:
        return items
    from rich.console import Console
    from rich.progress import track

    return track(items, description=what, console=Console(stderr=True), transient=True)


def mmc_exact(
    region: MultiPolygon, nozzle: Nozzle, machine: Machine, *, settings: Settings = DEFAULT_SETTINGS
) -> MMCResult:
    """The exact vector engine: P, S and the lost area with certified bounds.

    Parameters
    ----------
    region
        The layer target G, already validated (:func:`printability.model.geometry.as_region`).
    nozzle, machine
        Any nozzle; a separable machine (``xy`` or ``ttr``).
    settings
        ``quad_segs`` (chords per quarter circle), ``angle_step`` (T-T-R
        sampling, degrees; ``None`` uses the machine's), ``progress``.

    Returns
    -------
    MMCResult
        ``motion.regions``: P_φ per sampled angle (an inner approximation:
        every position keeps the whole nozzle in G). ``as_built``: S_inner ⊆
        S ⊆ G. ``lost_area`` = λ(G) − λ(S_inner). ``lost_area_bounds``:
        certified, also covering angles between samples on T-T-R (module
        docstring). ``extra["as_built_outer"]``: the outer S.

    Raises
    ------
    MMCInternalError
        When P misses a point of G farther than 2.5 nozzle reaches from ∂G
        (:func:`_check_p_inner`): the nozzle certainly fits there, so the
        computation failed; reporting "everything lost" would be nonsense.

    Notes
    -----
    Approximation: curved footprints are offset with ``quad_segs`` chords per
    quarter circle; straight offsets are exact and arcs deviate by at most
    a·(1/κ − 1) for semi-major a (about 7·10⁻⁴·a at 32 segments), only near
    corners. Polygons and rectangles are exact up to floating point. Cost: see
    the module docstring; linear in the number of sampled angles.
    """
    if not machine.separable:
        raise InputError(
            f"the exact engine needs a separable machine (xy or ttr); machine {machine.name!r} "
            "is a joint chain: use engine='sampled'"
        )
    t0 = time.perf_counter()
    q = settings.quad_segs
    g = region if isinstance(region, MultiPolygon) else as_multi(region)
    angles, gap, wrap = sampled_angles(nozzle, machine, settings)
    delta = angular_margin(nozzle, gap)
    results: list[_AngleResult] = []
    deep: tuple[float, list[tuple[float, float, float]]] | None = None
    for phi in _progress(list(angles), settings.progress, "exact MMC over angles"):
        placed = [_place(f, nozzle.mount_angle + float(phi)) for f in nozzle.footprints]
        res_phi = _one_angle(g, placed, delta, q)
        if deep is None:  # the reach does not change with the angle
            reach = max(_reach(o) for o in placed)
            deep = (reach, _deep_points(g, reach))
        _check_p_inner(g, res_phi.p_inner, *deep, float(phi))
        results.append(res_phi)

    s_in = as_multi(shapely.union_all([r.s_inner for r in results]))
    # safety net: S ⊆ G holds by construction; should a GEOS failure break it,
    # clip (true S ⊆ G, so clipping keeps S_inner ⊆ S) and say so
    leak = float(shapely.difference(s_in, g).area)
    if leak > 1e-9 * float(g.area):
        s_in = as_multi(shapely.intersection(s_in, g))
    s_out = as_multi(shapely.intersection(shapely.union_all([r.s_outer for r in results]), g))
    target_area = float(g.area)
    built = float(s_in.area)
    lost = max(target_area - built, 0.0)
    lo = max(target_area - float(s_out.area), 0.0)
    lo = min(lo, lost)  # S_inner ⊆ S_outer in exact arithmetic; rounding must not invert

    pieces = [polygons_of(r.p_inner) for r in results]
    components = _components(pieces, angles, wrap)
    curved = [f.a for f in nozzle.footprints if f.conic]
    kappa = chord_factor(q)
    notes = []
    if curved:
        notes.append(f"curved orifices offset with {q} chords per quarter circle; boundary "
                     f"error ≤ {max(curved) * (1 / kappa - 1):.2g} mm")
    if len(angles) > 1:
        notes.append(f"{len(angles)} sampled angles, largest gap {gap:.4g}°; bounds cover the "
                     f"continuous range (δ = {delta:.3g} mm)")
    if leak > 1e-9 * float(g.area):
        notes.append(f"internal check: {leak:.3g} mm² of the as-built region fell outside "
                     "the part and was clipped (a geometry-library failure; please report)")
    if all(r.p_inner.is_empty for r in results):
        notes.append("the nozzle fits nowhere in the region: nothing is printed")
    return MMCResult(
        engine="exact",
        nozzle=nozzle,
        machine=machine,
        target=g,
        as_built=s_in,
        target_area=target_area,
        as_built_area=built,
        lost_area=lost,
        lost_area_bounds=(lo, lost),
        motion=MotionRestriction(angles=angles, regions=tuple(r.p_inner for r in results)),
        components=components,
        resolution=max(curved) * (1 / kappa - 1) if curved else 0.0,
        angle_step=gap,
        elapsed=time.perf_counter() - t0,
        notes=tuple(notes),
        extra={"as_built_outer": s_out, "angular_margin": delta},
    )


def _components(pieces: list[list[Polygon]], angles: np.ndarray, wrap: bool) -> Components:
    boxes = [[p.bounds for p in row] for row in pieces]
    flat = {id(p): i for row in pieces for i, p in enumerate(row)}

    def overlap(k: int, a: Polygon, k2: int, b: Polygon) -> bool:
        ba, bb = boxes[k][flat[id(a)]], boxes[k2][flat[id(b)]]
        if ba[2] < bb[0] or bb[2] < ba[0] or ba[3] < bb[1] or bb[3] < ba[1]:
            return False
        return bool(a.intersects(b))

    labels = component_labels(pieces, overlap, wrap=wrap)
    count = 1 + max((max(row) for row in labels if row), default=-1)
    members: list[list[Polygon]] = [[] for _ in range(count)]
    for row, lab in zip(pieces, labels, strict=True):
        for p, c in zip(row, lab, strict=True):
            members[c].append(p)
    geoms = tuple(shapely.union_all(m) for m in members)
    ranges = tuple(angle_ranges(labels, angles)) if count else ()
    return Components(count=count, geometries=geoms, angle_ranges=ranges)

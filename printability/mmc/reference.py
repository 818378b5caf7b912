"""Reference MMC engine: the seed paper's literal inverse-trajectory method.

For a point Y of the plane, its inverse trajectory is T̂_Y = ∪_u m(u)⁻¹·Y: where Y
lands in the nozzle frame at every configuration u. The nozzle covers Y at
configuration u exactly when m(u)⁻¹·Y ∈ A⁰. So, on a separable machine
(u = (t, φ), m(u)⁻¹·Y = R(−φ)(Y − t)):

* sample points Q of G (a lattice inside G) and points Y of ∂G (dense along every
  ring);
* discretise Ω: t on the lattice hℤ² (h = ``settings.resolution``), φ from
  :meth:`Machine.angles`;
* C[u]: some interior sample Q has m(u)⁻¹·Q in the orifice; B[u]: some boundary
  sample Y has m(u)⁻¹·Y in the orifice; **P = C \\ B** (for a head with several
  orifices: every orifice in C and none in B, see docs/design.md §2);
* S = ∪_{u∈P} A^u as a shapely union of placed footprints.

At a fixed angle the inverse trajectory of Y, {t : m(t, φ)⁻¹·Y ∈ A⁰} = Y − R(φ)A⁰,
is rasterised on the lattice row by row (a numba kernel: the row's intervals by the
even-odd rule over the footprint's edges, accumulated in difference arrays), so
every (sample, lattice position) pair is decided exactly. It is slow and literal on
purpose: it shares no geometry code with the fast engines and checks them.

Error and how it is made one-sided
----------------------------------
Boundary samples are at most δ apart along ∂G (δ = ``boundary_spacing``, default
h/2), so a nozzle can graze ∂G between two samples by up to δ/2 and B would miss
it; and P is only known at lattice points. Both are compensated so that the
reported P and S are *conservative* (never a configuration that puts material
outside G):

* the B test uses the orifice grown by ε = h/√2 + δ/2 (exact offset test against
  the outer polygon of a curved orifice). Then every t in the lattice cell (a
  square of side h) of a lattice point that passes is a true configuration of P
  (proof: a boundary point inside A + t lies within δ/2 of a sample, and t within
  h/√2 of the lattice point), so P is reported as the union of those cells and
  S_inner = ∪ cells ⊕ R(φ)A ⊆ S ⊆ G.
* a second, optimistic pass shrinks the orifice by ρ' = h/√2 + r_max·Δφ/2
  (r_max = :attr:`Nozzle.radius`, Δφ the angular gap) and counts only boundary
  samples *strictly inside*: every configuration of the true P, at any angle,
  has its nearest lattice point and nearest sampled angle in that optimistic set
  P', so S ⊆ ∪ cells(P') ⊕ (R(φ)A ⊕ D(r_max·Δφ/2)).

Hence ``lost_area_bounds = (λ(G) − λ(S_outer ∩ G), λ(G) − λ(S_inner))`` contains
the exact lost area of the continuous machine; ``lost_area`` is the conservative
upper end (S_inner is what the engine promises). Their gap is about
perimeter(S) × (ε + ρ' + h), i.e. O(h): halving h halves it and quadruples the
lattice. Curved orifices are polygons with ``4·settings.quad_segs`` vertices,
inner ones for what is claimed printable and outer ones for what must be avoided.

Complexity: O(#angles × #samples × lattice rows per footprint × footprint edges)
plus O(#angles × #lattice points); the work and memory are estimated before
anything heavy and refused above ``max_work`` / ``settings.max_memory``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numba
import numpy as np
import shapely
from shapely.geometry import MultiPolygon
from shapely.geometry.base import BaseGeometry

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.mmc._reference_setup import (
    LatticeWindow,
    Plan,
    ProbeShape,
    ProbeShapes,
    Window,
    boundary_samples,
    budget,
    interior_samples,
    plan_run,
    probe_shapes,
)
from printability.mmc.components import angle_ranges, component_labels
from printability.mmc.orifices import (
    Orifice,
    angle_gap,
    cell_footprint_union,
    grid_rectangles,
    offset_orifice,
    orifices_of,
)
from printability.mmc.result import Components, MMCResult, MotionRestriction
from printability.model.geometry import polygons_of
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle
from printability.settings import DEFAULT_SETTINGS, Settings

_guard_kernel_caches()  # the cache check runs before a kernel here loads

# the orifice helpers live in printability.mmc.orifices; re-exported here, where they began
__all__ = [
    "DEFAULT_MAX_WORK",
    "Orifice",
    "angle_gap",
    "cell_footprint_union",
    "grid_rectangles",
    "mmc_reference",
    "offset_orifice",
    "orifices_of",
]

DEFAULT_MAX_WORK = 5e10
"""Default budget of the reference engine, in edge visits (about half a minute)."""

# --------------------------------------------------------------------------- numba kernel


@numba.njit(cache=True)
def _mark_inverse_trajectories(px, py, shape, lattice, diff, xs):  # pragma: no cover
    """Rasterise the inverse trajectories of sample points onto the position lattice.

    At a fixed angle φ the inverse trajectory of a point Y meets the (turned) test
    shape F (``shape``, a :class:`TurnedShape`) exactly at the positions t ∈ Y − F.
    For every sample Y = (px, py) and every row of ``lattice`` (a
    :class:`LatticeWindow`), the row's intersection with Y − F is a set of
    intervals (even-odd rule over F's edges, or the chord of a disk); each interval
    adds +1/−1 to the row's difference array ``diff`` so that, after a cumulative
    sum, a lattice point is covered when some sample's inverse trajectory reaches
    it. ``xs`` is scratch space for a row's crossings.
    """
    kind, strict = shape.kind, shape.strict
    dcx, dcy, dr = shape.dcx, shape.dcy, shape.dr
    ex0, ey0, ex1, ey1 = shape.ex0, shape.ey0, shape.ex1, shape.ey1
    h, ix0, iy0 = lattice.h, lattice.ix0, lattice.iy0
    ny = diff.shape[0]
    nx = diff.shape[1] - 1
    for m in range(len(px)):
        yx = px[m]
        yy = py[m]
        j0 = max(math.ceil((yy - shape.ymax) / h), iy0)
        j1 = min(math.floor((yy - shape.ymin) / h), iy0 + ny - 1)
        for j in range(j0, j1 + 1):
            yp = yy - j * h
            n = 0
            if kind == 0:
                d = yp - dcy
                q = dr * dr - d * d
                if q < 0.0 or (strict and q <= 0.0):
                    continue
                half = math.sqrt(q)
                xs[0] = dcx - half
                xs[1] = dcx + half
                n = 2
            else:
                for e in range(len(ex0)):
                    if (ey0[e] > yp) != (ey1[e] > yp):
                        x = ex0[e] + (yp - ey0[e]) * (ex1[e] - ex0[e]) / (ey1[e] - ey0[e])
                        k = n  # insertion sort: crossings are few
                        while k > 0 and xs[k - 1] > x:
                            xs[k] = xs[k - 1]
                            k -= 1
                        xs[k] = x
                        n += 1
            for p in range(0, n - 1, 2):
                lo = (yx - xs[p + 1]) / h
                hi = (yx - xs[p]) / h
                if strict:
                    i_lo = math.floor(lo) + 1
                    i_hi = math.ceil(hi) - 1
                else:
                    i_lo = math.ceil(lo)
                    i_hi = math.floor(hi)
                i_lo = max(i_lo, ix0)
                i_hi = min(i_hi, ix0 + nx - 1)
                if i_lo <= i_hi:
                    diff[j - iy0, i_lo - ix0] += 1
                    diff[j - iy0, i_hi - ix0 + 1] -= 1


# --------------------------------------------------------------------------- engine


@dataclass(frozen=True, eq=False)
class _Samples:
    """The interior samples Q, the boundary samples Y and the kernel's scratch row."""

    interior: np.ndarray
    boundary: np.ndarray
    scratch: np.ndarray


def _covered(shape: ProbeShape, pts: np.ndarray, win: Window, angle: float, h: float,
             scratch: np.ndarray) -> np.ndarray:
    """Lattice positions of ``win`` reached by the inverse trajectory of some point."""
    ix0, ix1, iy0, iy1 = win
    diff = np.zeros((iy1 - iy0 + 1, ix1 - ix0 + 2), dtype=np.int32)
    if not shape.empty and len(pts):
        _mark_inverse_trajectories(pts[:, 0], pts[:, 1], shape.turned(angle),
                                   LatticeWindow(h, ix0, iy0), diff, scratch)
    return np.cumsum(diff, axis=1)[:, :-1] > 0


def _feasible(c_shapes: list[ProbeShape], b_shapes: list[ProbeShape], samples: _Samples,
              win: Window, angle: float, h: float) -> np.ndarray | None:
    """P at one angle on the lattice window: every orifice in C and none in B."""
    ix0, ix1, iy0, iy1 = win
    if ix1 < ix0 or iy1 < iy0:
        return None
    mask = np.ones((iy1 - iy0 + 1, ix1 - ix0 + 1), dtype=bool)
    for c_shape, b_shape in zip(c_shapes, b_shapes, strict=True):
        mask &= _covered(c_shape, samples.interior, win, angle, h, samples.scratch)
        if not mask.any():
            break
        mask &= ~_covered(b_shape, samples.boundary, win, angle, h, samples.scratch)
    return mask


def _cell_rectangles(mask: np.ndarray, win: Window, h: float) -> np.ndarray:
    """The lattice cells of ``mask`` (on window ``win``) as few rectangles (k, 4)."""
    ix0, _, iy0, _ = win
    xs = (ix0 + np.arange(mask.shape[1])) * h
    ys = (iy0 + np.arange(mask.shape[0])) * h
    return grid_rectangles(mask, xs, ys, h)


@dataclass(frozen=True, eq=False)
class _Passes:
    """What both passes found: P's cells per angle, the pieces of S_inner and S_outer,
    and the number of feasible cells."""

    regions: list[BaseGeometry]
    s_inner: list[BaseGeometry]
    s_outer: list[BaseGeometry]
    n_cells: int


def _run_passes(plan: Plan, shapes: ProbeShapes, samples: _Samples, windows: list[Window],
                windows_out: list[Window]) -> _Passes:
    """The conservative pass (P, S_inner) and the optimistic one (S_outer) at every angle."""
    h = plan.h
    regions: list[BaseGeometry] = []
    s_inner: list[BaseGeometry] = []
    s_outer: list[BaseGeometry] = []
    pieces_in = tuple(p for o in plan.orifices for p in o.inner_pieces)
    pieces_out = tuple(p for o in plan.orifices for p in o.outer_pieces)
    n_cells = 0
    for k, a in enumerate(plan.angles):
        mask = _feasible(shapes.c_in, shapes.b_in, samples, windows[k], float(a), h)
        if mask is not None and mask.any():
            rects = _cell_rectangles(mask, windows[k], h)
            n_cells += int(mask.sum())
            regions.append(shapely.union_all(shapely.box(*rects.T)))
            s_inner.extend(cell_footprint_union(rects, pieces_in, float(a)))
        else:
            regions.append(MultiPolygon())
        if plan.has_outer:
            mask = _feasible(shapes.c_out, shapes.b_out, samples, windows_out[k], float(a), h)
            if mask is not None and mask.any():
                rects = _cell_rectangles(mask, windows_out[k], h)
                s_outer.extend(cell_footprint_union(rects, pieces_out, float(a),
                                                    grow=plan.spin))
    return _Passes(regions, s_inner, s_outer, n_cells)


def _components(regions: list[BaseGeometry], angles: np.ndarray, wrap: bool) -> Components:
    """Components of P: pieces per angle, joined when they overlap at neighbouring angles."""
    pieces = [polygons_of(r) for r in regions]
    labels = component_labels(pieces, lambda _k, a, _k2, b: a.intersects(b), wrap=wrap)
    count = 1 + max((max(row) for row in labels if row), default=-1)
    members: list[list[BaseGeometry]] = [[] for _ in range(count)]
    for k, row in enumerate(labels):
        for i, c_id in enumerate(row):
            members[c_id].append(pieces[k][i])
    return Components(
        count=count,
        geometries=tuple(shapely.union_all(m) for m in members),
        angle_ranges=tuple(angle_ranges(labels, angles)),
    )


def mmc_reference(
    region: BaseGeometry,
    nozzle: Nozzle,
    machine: Machine,
    *,
    settings: Settings = DEFAULT_SETTINGS,
    boundary_spacing: float | None = None,
    max_work: float = DEFAULT_MAX_WORK,
) -> MMCResult:
    """MMC by the literal inverse-trajectory method (separable machines, small inputs).

    Parameters
    ----------
    region
        G, a validated MultiPolygon (see :func:`printability.model.geometry.as_region`), mm.
    nozzle, machine
        The nozzle and an ``xy`` or ``ttr`` machine.
    settings
        ``resolution`` is the lattice spacing h of the positions t (mm);
        ``angle_step`` overrides the machine's rotary step; ``quad_segs`` sets the
        polygons of curved orifices.
    boundary_spacing
        Largest distance δ between boundary samples along ∂G, mm (default h/2).
    max_work
        Refuse (ResourceError) when the estimated number of polygon-vertex
        operations exceeds this.

    Returns
    -------
    MMCResult
        ``as_built`` is S_inner (conservative), ``lost_area`` its loss (the upper
        end of ``lost_area_bounds``); ``motion.regions`` the union of the lattice
        cells of P per angle (every point of them a true configuration of P).

    Raises
    ------
    InputError
        Chain machine, or a resolution too coarse for the orifice.
    ResourceError
        The estimated work exceeds ``max_work``.

    Notes
    -----
    Error: the bounds' width is O(h) (see the module docstring). Cost: see the
    module docstring; the numba kernel compiles on first use (a few seconds,
    cached on disk).
    """
    t_start = time.perf_counter()
    g = region
    plan = plan_run(nozzle, machine, settings, boundary_spacing)
    h, delta = plan.h, plan.delta
    shapes = probe_shapes(plan)
    windows, windows_out, work = budget(g, plan, shapes, max_work, settings.max_memory)

    q_pts = interior_samples(g, plan.q_spacing)
    y_pts = boundary_samples(g, delta)
    n_edges = [len(s.edges) for s in (*shapes.b_in, *shapes.c_in, *shapes.c_out)]
    samples = _Samples(q_pts, y_pts, np.zeros(max([*n_edges, 2]) + 2))
    passes = _run_passes(plan, shapes, samples, windows, windows_out)

    as_built = shapely.union_all(passes.s_inner) if passes.s_inner else MultiPolygon()
    target_area = float(g.area)
    as_built_area = float(as_built.area)
    lost_hi = max(0.0, target_area - as_built_area)
    if plan.has_outer:
        outer_geom = shapely.union_all(passes.s_outer) if passes.s_outer else MultiPolygon()
        lost_lo = max(0.0, target_area - float(shapely.intersection(outer_geom, g).area))
    else:
        lost_lo = 0.0
    lost_lo = min(lost_lo, lost_hi)

    notes = (
        f"reference: {len(y_pts):,} boundary samples ≤ {delta:g} mm apart, {len(q_pts):,} "
        f"interior samples every {plan.q_spacing:.3g} mm, positions every {h:g} mm, "
        f"{len(plan.angles)} angle(s); B tested with the nozzle grown by {plan.eps:.3g} mm so "
        f"P is conservative; bounds from a pass with it shrunk by {plan.rho_out:.3g} mm",
        *plan.notes,
    )
    return MMCResult(
        engine="reference",
        nozzle=nozzle,
        machine=machine,
        target=g,
        as_built=as_built,
        target_area=target_area,
        as_built_area=as_built_area,
        lost_area=lost_hi,
        lost_area_bounds=(lost_lo, lost_hi),
        motion=MotionRestriction(angles=plan.angles, regions=tuple(passes.regions)),
        components=_components(passes.regions, plan.angles, plan.wrap),
        resolution=h,
        angle_step=plan.gap if plan.turning else 0.0,
        elapsed=time.perf_counter() - t_start,
        notes=notes,
        extra={"boundary_samples": len(y_pts), "interior_samples": len(q_pts),
               "boundary_spacing": delta, "interior_spacing": plan.q_spacing,
               "grow": plan.eps, "shrink": plan.rho_out, "feasible_cells": passes.n_cells,
               "work_estimate": work},
    )

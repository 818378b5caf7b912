"""Sampled MMC engine: any machine chain, by sampling Ω and testing containment.

Machines whose translations depend on their rotations (a polar printer, a SCARA
arm) are not separable: there is no erosion per angle to compute. This engine
samples the joint space Ω on the product grid of the joints' own steps
(:meth:`Machine.joint_grid`), places the nozzle at every sample with
:meth:`Machine.pose` and tests **A^u ⊆ G directly**:

* P = the feasible samples. For a connected orifice, A^u lies in the interior of
  G exactly when one of its points is inside G (``shapely.contains_xy``) and no
  edge of ∂G meets it. A numba kernel (:mod:`printability.mmc._containment`) tests
  the edges of ∂G near the placed orifice (bucketed) against the *true* shape in
  the orifice's frame: an ellipse or circle (the edge mapped to the unit disk
  comes within distance 1 of its centre), a rectangle (Liang–Barsky clipping) or
  a polygon (edge crossings, or an edge end inside). Touching ∂G counts as leaving
  G (P = C \\ B), with a 1e-9 relative margin for tangencies blurred by rounding.
  Never a configuration that puts material outside G; every orifice of a head
  must pass.
* S = the union of the footprints swept between consecutive feasible samples
  along each joint (on the XY/T-T-R lattice, whose step is far below the nozzle
  size, along X only). Along a prismatic joint the nozzle translates and the
  sweep of a convex piece is exactly the convex hull of its end placements: a
  whole run of feasible samples is one hull. Along a revolute joint the nozzle
  turns about the joint axis by θ per group of steps; the hull of the group's
  end placements differs from the true arc sweep: it misses at most the arc's
  sagitta s = ρ(1 − cos(θ/2)) and sticks out by at most
  e = ρ·max_λ|λ + (1 − λ)e^{iθ} − e^{i(1−λ)θ}| + θ·D/4 (≈ ρθ²/8 + θD/4; ρ the
  distance from the axis to the farthest nozzle point, found per group from the
  two poses; D the orifice's diameter, 0 for a circle). Groups are sized so that
  e ≤ ``settings.chord_tolerance`` where possible. Every hull is checked inside
  G with the outer polygons grown by s, and kept only then (a failed translation
  run is retried without its end samples, then halved; a failed rotation group
  pairwise); samples left uncovered add their own footprint. So S ⊆ G always.
  Hulls are drawn with inner polygons of as few vertices as keep them within
  ``chord_tolerance`` of the curve (the union's cost grows with vertices);
  non-convex orifices are swept piece by piece (triangulated). The T-T-R rotary
  axis (a turn about the nozzle's own origin) is not swept: S is the union over
  the sampled angles.
* Bounds. Every configuration u of Ω is within half a step of a sample in each
  joint, so each nozzle point is within L = Σ_j lever_j·step_j/2 of where it is at
  that sample (lever: 1 for a prismatic joint, the largest distance from the axis
  to the nozzle, per radian, for a revolute one; on XY/T-T-R L = h/√2 + r_max·Δφ/2).
  A feasible u therefore has a sample whose orifices shrunk by L fit in G (an
  ellipse E(a, b) is shrunk to E(ka, kb), k = 1 − L/b, which lies inside its
  erosion), so S ⊆ S_outer = ∪ over those samples of A^u ⊕ D(L), and
  ``lost_area_bounds = (λ(G) − λ(S_outer ∩ G), λ(G) − λ(S) + 2e·perimeter(S))``.
  When L exceeds an orifice's inscribed radius the lower bound is 0 (a note says
  so), unless no sample brings the nozzle near G at all.

On ``xy`` and ``ttr`` machines the same code runs on the joints X, Y (a lattice
of spacing ``settings.resolution``, padded so every feasible position has its
nearest lattice point in it) and the nozzle angle (from :meth:`Machine.angles`),
so its results can be compared with the separable engines'.

Components of P are the connected components of the feasible samples in the
joint grid (``scipy.ndimage.label``, face neighbours; full-turn revolute joints
and T-T-R angles covering a whole symmetry period wrap).

Cost: one pose, one point-in-G test and a few edge tests per sample (chunks of
2¹⁸; values of the first joint whose second joint axis cannot bring the nozzle
to G's bounding box are skipped), then a union of O(#runs) hulls. The number of
samples, the product of the joints' value counts, and the memory are estimated
up front and refused above ``max_samples`` or ``settings.max_memory`` with a
ResourceError that suggests coarser steps.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import shapely
from scipy import ndimage
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.base import BaseGeometry

from printability.errors import ResourceError
from printability.machine import Machine
from printability.mmc._containment import (
    boundary_edges,
    containment_test,
    run_containment_test,
)
from printability.mmc.reference import (
    Orifice,
    angle_gap,
    grid_rectangles,
    orifices_of,
)
from printability.mmc.result import Components, MMCResult, MotionRestriction
from printability.nozzle import Nozzle
from printability.settings import DEFAULT_SETTINGS, Settings

__all__ = ["DEFAULT_MAX_SAMPLES", "SampleSpace", "mmc_sampled", "sample_space"]

DEFAULT_MAX_SAMPLES = 60_000_000
"""Default largest number of joint-space samples the sampled engine accepts."""

_CHUNK = 1 << 18
_MAX_COMPONENT_POINTS = 200_000


# --------------------------------------------------------------------------- sample space


@dataclass(frozen=True, eq=False)
class SampleSpace:
    """The sampled joint space Ω of a machine, and how far a sample is from any u.

    Attributes
    ----------
    names
        Joint names (``X``, ``Y``, ``C`` on separable machines).
    kinds
        ``prismatic``, ``revolute`` (about a joint axis away from the nozzle) or
        ``spin`` (the T-T-R rotary axis, about the nozzle origin).
    values
        Sampled values per joint (mm or degrees).
    wrap
        Whether the last value neighbours the first (full turn / symmetry period).
    steps
        Largest spacing between consecutive values, per joint.
    levers
        Largest displacement of a nozzle point per unit of the joint (1 for a
        prismatic joint; mm per degree for a rotation).
    reaches
        Largest distance from the joint's axis to a nozzle point, mm (0 if prismatic).
    slack
        L: every configuration of Ω has a sample whose footprint is within L mm
        (every nozzle point moves at most L), mm.
    pose
        ``u (k, p) -> (phi degrees, t (k, 2) mm)``.
    """

    names: tuple[str, ...]
    kinds: tuple[str, ...]
    values: tuple[np.ndarray, ...]
    wrap: tuple[bool, ...]
    steps: tuple[float, ...]
    levers: tuple[float, ...]
    reaches: tuple[float, ...]
    slack: float
    pose: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(v) for v in self.values)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64)) if self.values else 0

    def joint_vectors(self, flat: np.ndarray) -> np.ndarray:
        """Joint vectors (k, p) of flat sample indices (C order over :attr:`shape`)."""
        idx = np.unravel_index(flat, self.shape)
        return np.column_stack([v[i] for v, i in zip(self.values, idx, strict=True)])


def _lattice(lo: float, hi: float, h: float) -> np.ndarray:
    return np.arange(math.ceil(lo / h - 1e-9), math.floor(hi / h + 1e-9) + 1) * h


def sample_space(
    region: BaseGeometry, nozzle: Nozzle, machine: Machine, *, settings: Settings
) -> SampleSpace:
    """The joint-space sampling the sampled engine uses for this region and machine.

    Chains use their joints' values; ``xy``/``ttr`` use a lattice of spacing
    ``settings.resolution`` restricted to positions where the nozzle fits in the
    region's bounding box at some sampled angle, and the machine's angles.
    """
    if machine.kind == "chain":
        values, kinds, wrap, steps, levers, reaches = [], [], [], [], [], []
        joints = machine.joints
        for j, joint in enumerate(joints):
            vals = joint.values()
            span = joint.hi - joint.lo
            full = joint.kind == "revolute" and span >= 360.0 - 1e-9
            step = (360.0 / len(vals)) if full else (span / max(1, len(vals) - 1))
            if joint.kind == "revolute":
                reach = sum(math.hypot(*jj.offset) + (max(abs(jj.lo), abs(jj.hi))
                                                      if jj.kind == "prismatic" else 0.0)
                            for jj in joints[j + 1:])
                reach += math.hypot(*machine.tool_offset) + nozzle.radius
                lever = math.radians(1.0) * reach
            else:
                reach, lever = 0.0, 1.0
            values.append(np.asarray(vals, dtype=float))
            kinds.append(joint.kind)
            wrap.append(full and len(vals) > 2)
            steps.append(float(step))
            levers.append(lever)
            reaches.append(reach)
        slack = sum(lv * st / 2 for lv, st in zip(levers, steps, strict=True))
        return SampleSpace(tuple(j.name for j in joints), tuple(kinds), tuple(values),
                           tuple(wrap), tuple(steps), tuple(levers), tuple(reaches), slack,
                           machine.pose)

    h = float(settings.resolution)
    period = nozzle.symmetry_period
    angles = np.asarray(machine.angles(step=settings.angle_step, period=period), dtype=float)
    gap, wrap_a = angle_gap(machine, angles, period)
    turning = machine.kind == "ttr" and period != 0.0 and len(angles) > 1
    orifices = orifices_of(nozzle, quad_segs=settings.quad_segs)
    pts = np.concatenate([_ring(o.inner) for o in orifices])
    gminx, gminy, gmaxx, gmaxy = region.bounds
    lo = np.array([np.inf, np.inf])
    hi = np.array([-np.inf, -np.inf])
    for a in angles:
        c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
        p = pts @ np.array([[c, s], [-s, c]])
        lo = np.minimum(lo, [gminx - p[:, 0].min(), gminy - p[:, 1].min()])
        hi = np.maximum(hi, [gmaxx - p[:, 0].max(), gmaxy - p[:, 1].max()])
    spin_lever = math.radians(1.0) * nozzle.radius
    slack = h / math.sqrt(2.0) + (spin_lever * gap / 2 if turning else 0.0)
    # positions where the nozzle fits the bounding box, padded so that the nearest sample
    # of every feasible configuration is in the grid (the optimistic pass needs it)
    pad = slack + h
    xs, ys = _lattice(lo[0] - pad, hi[0] + pad, h), _lattice(lo[1] - pad, hi[1] + pad, h)
    names, kinds = ("X", "Y"), ("prismatic", "prismatic")
    values: tuple[np.ndarray, ...] = (xs, ys)
    wraps, steps, levers, reaches = (False, False), (h, h), (1.0, 1.0), (0.0, 0.0)
    if machine.kind == "ttr":
        names += (machine.rotary_letter,)
        kinds += ("spin",)
        values += (angles,)
        wraps += (wrap_a,)
        steps += (gap,)
        levers += (spin_lever if turning else 0.0,)
        reaches += (nozzle.radius,)

    def pose(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u = np.atleast_2d(u)
        phi = u[:, 2].copy() if u.shape[1] > 2 else np.zeros(len(u))
        return phi, u[:, :2].copy()

    return SampleSpace(names, kinds, values, wraps, steps, levers, reaches, slack, pose)


# --------------------------------------------------------------------------- placing


def _placed(coords: np.ndarray, phi: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``coords`` (n, 2) in the nozzle frame placed at k poses → (k, n, 2)."""
    a = np.deg2rad(phi)[:, None]
    c, s = np.cos(a), np.sin(a)
    x = c * coords[None, :, 0] - s * coords[None, :, 1] + t[:, :1]
    y = s * coords[None, :, 0] + c * coords[None, :, 1] + t[:, 1:2]
    return np.stack([x, y], axis=-1)


def _ring(poly: BaseGeometry) -> np.ndarray:
    """Closed exterior ring coordinates of a polygon (n + 1, 2)."""
    return np.asarray(poly.exterior.coords)


# --------------------------------------------------------------------------- sweeping


def _runs(mask: np.ndarray, wrap: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Runs of True along the last axis of a 2-D mask: (row, start, length).

    With ``wrap`` a run touching the end continues at the start (indices mod n);
    a row that is entirely True is one run starting at 0 of length n.
    """
    n = mask.shape[1]
    padded = np.concatenate([np.zeros((mask.shape[0], 1), bool), mask,
                             np.zeros((mask.shape[0], 1), bool)], axis=1)
    d = np.diff(padded.astype(np.int8), axis=1)
    r_s, c_s = np.nonzero(d == 1)
    _, c_e = np.nonzero(d == -1)
    rows, starts, lengths = r_s, c_s, c_e - c_s
    if wrap and n > 2 and len(rows):
        full = lengths == n
        first = (starts == 0) & ~full
        last = (starts + lengths == n) & ~full
        rows_first = set(rows[first].tolist())
        join = last & np.isin(rows, list(rows_first))
        if join.any():
            # extend the last run of those rows by the row's first run, drop the first run
            first_len = dict(zip(rows[first].tolist(), lengths[first].tolist(), strict=True))
            lengths = lengths.copy()
            lengths[join] += np.array([first_len[r] for r in rows[join].tolist()])
            drop = first & np.isin(rows, rows[join])
            rows, starts, lengths = rows[~drop], starts[~drop], lengths[~drop]
    return rows, starts, lengths


def _chord_excess(theta: float) -> float:
    """max_λ |λ + (1 − λ)e^{iθ} − e^{i(1−λ)θ}| (θ radians), slightly over-estimated.

    How far a point of the chord between a point and its rotation by θ can be from
    the arc, per unit of radius (≈ θ²/8).
    """
    lam = np.linspace(0.0, 1.0, 2001)
    z = lam + (1 - lam) * np.exp(1j * theta) - np.exp(1j * (1 - lam) * theta)
    return float(np.abs(z).max()) * 1.01 + 1e-15


def _hulls(parts: list[np.ndarray]) -> np.ndarray:
    """Convex hulls of the point sets ``concatenate(parts, axis=1)`` (k, m, 2) → k polygons."""
    pts = np.concatenate(parts, axis=1)
    return shapely.convex_hull(shapely.linestrings(pts))


@dataclass(frozen=True, eq=False)
class _Pieces:
    """Convex pieces of every orifice, as vertex arrays in the nozzle frame."""

    inner: tuple[np.ndarray, ...]   # to draw S (inside the true orifice)
    outer: tuple[np.ndarray, ...]   # to check (contain the true orifice)
    shape_diameter: float           # 0 when every orifice is a circle (turning it is moot)


def _pieces(orifices: tuple[Orifice, ...], grow: float = 0.0) -> _Pieces:
    inner = tuple(_ring(p)[:-1] for o in orifices for p in o.inner_pieces)
    outs = []
    for o in orifices:
        for p in o.outer_pieces:
            q = p.buffer(grow, join_style="mitre", mitre_limit=1e3) if grow > 0 else p
            outs.append(_ring(q)[:-1])
    diam = 0.0 if all(o.disk is not None for o in orifices) else max(
        o.diameter + 2 * grow for o in orifices)
    return _Pieces(inner, tuple(outs), diam)


def _rotation_radius(phi_a: np.ndarray, t_a: np.ndarray, phi_b: np.ndarray,
                     t_b: np.ndarray) -> np.ndarray:
    """Distance from the tool origin to the centre of the rotation taking pose a to pose b.

    Pose b is pose a turned by θ = φ_b − φ_a about a centre c:
    t_b = R(θ)(t_a − c) + c, so (I − R(θ))·c = t_b − R(θ)·t_a.
    """
    th = np.deg2rad(phi_b - phi_a)
    c, s = np.cos(th), np.sin(th)
    rx = t_b[:, 0] - (c * t_a[:, 0] - s * t_a[:, 1])
    ry = t_b[:, 1] - (s * t_a[:, 0] + c * t_a[:, 1])
    det = 2.0 * (1.0 - c)
    with np.errstate(divide="ignore", invalid="ignore"):
        cx = ((1 - c) * rx - s * ry) / det
        cy = (s * rx + (1 - c) * ry) / det
    out = np.hypot(t_a[:, 0] - cx, t_a[:, 1] - cy)
    return np.where(det > 1e-18, out, 0.0)


def _sweep(
    space: SampleSpace,
    mask: np.ndarray,
    orifices: tuple[Orifice, ...],
    fine: tuple[Orifice, ...],
    nozzle_radius: float,
    g: BaseGeometry,
    *,
    tolerance: float,
    axes: list[int],
    verify: bool,
    grow: float = 0.0,
) -> tuple[list[BaseGeometry], float, np.ndarray]:
    """Polygons sweeping the footprints of ``mask``'s samples along the given joints.

    ``orifices`` draw the polygons (few vertices); ``fine`` (the settings' polygons)
    check translations, whose hulls hug ∂G closely. Runs of consecutive True samples
    along each joint are cut into groups: a whole run for a prismatic joint; for a
    revolute one, as many steps as keep the hull within ``tolerance`` of the arc
    sweep. With ``verify`` (the as-built S) a
    group's hull of inner pieces is kept only when the hull of the outer pieces,
    grown by the arc's sagitta, lies inside G; failed groups are retried pairwise.
    Without (the outer bound), every group's hull of all its placements of the
    outer pieces grown by ``grow`` is kept.

    Returns
    -------
    polygons, excess, covered
        The polygons; the largest distance e (mm) by which a kept revolute hull can
        stick out of the true sweep; which samples lie in a kept group.
    """
    out: list[BaseGeometry] = []
    excess = 0.0
    covered = np.zeros(mask.shape, dtype=bool)
    flat_ids = np.arange(mask.size).reshape(mask.shape)
    base = _pieces(orifices, grow)
    fine_outer = _pieces(fine, grow).outer
    for j in axes:
        n = mask.shape[j]
        if n < 2:
            if not verify:  # every sample still needs a polygon in the outer bound
                seg = np.flatnonzero(mask.reshape(-1))
                ids2 = flat_ids.reshape(-1, 1)
                z = np.zeros(len(seg), dtype=np.int64)
                _sweep_segments(space, ids2, seg, z, z, 1, j, base, g, verify=False,
                                out=out, covered=covered, step_rad=0.0,
                                nozzle_radius=nozzle_radius)
            continue
        kind = space.kinds[j]
        m2 = np.moveaxis(mask, j, -1).reshape(-1, n)
        ids2 = np.moveaxis(flat_ids, j, -1).reshape(-1, n)
        rows, starts, lengths = _runs(m2, space.wrap[j])
        if not len(rows):
            continue
        step_rad = math.radians(space.steps[j]) if kind != "prismatic" else 0.0
        reach = space.reaches[j]
        if kind == "prismatic":
            group = max(int(lengths.max()) - 1, 1)
        else:
            group = 1
            while group < n and (reach * _chord_excess((group + 1) * step_rad)
                                 + (group + 1) * step_rad * base.shape_diameter / 4
                                 ) <= tolerance:
                group += 1
        seg_rows, seg_a, seg_b = [], [], []
        closed = space.wrap[j]
        for r, s0, ln in zip(rows.tolist(), starts.tolist(), lengths.tolist(), strict=True):
            if ln == 1:
                seg_rows.append(r)
                seg_a.append(s0)
                seg_b.append(s0)
                continue
            end = ln if (closed and ln == n) else ln - 1  # a full turn closes on itself
            k = 0
            while k < end:
                e = min(k + group, end)
                seg_rows.append(r)
                seg_a.append(s0 + k)
                seg_b.append(s0 + e)
                k = e
        rows_a = np.asarray(seg_rows, dtype=np.int64)
        a_a = np.asarray(seg_a, dtype=np.int64)
        b_a = np.asarray(seg_b, dtype=np.int64)
        kept, exc = _sweep_segments(space, ids2, rows_a, a_a, b_a, n, j, base, g,
                                    verify=verify, out=out, covered=covered,
                                    step_rad=step_rad, nozzle_radius=nozzle_radius,
                                    check=fine_outer if kind == "prismatic" else None)
        excess = max(excess, exc)
        bad = np.flatnonzero(~kept & (b_a - a_a > 1))
        if verify and kind == "prismatic":
            # a translation's hull is its exact sweep: it fails because some placement
            # grazes ∂G, most often an end of the run. Try the run without its first
            # and/or last sample, then halves, down to single steps.
            rows_q, a_q, b_q = rows_a[bad], a_a[bad], b_a[bad]
            while len(rows_q):
                tries = [(a_q, b_q - 1), (a_q + 1, b_q), (a_q + 1, b_q - 1)]
                left = np.ones(len(rows_q), dtype=bool)
                for ta, tb in tries:
                    sel = np.flatnonzero(left & (tb - ta >= 1))
                    if not len(sel):
                        continue
                    ok_t, _ = _sweep_segments(space, ids2, rows_q[sel], ta[sel], tb[sel], n, j,
                                              base, g, verify=True, out=out, covered=covered,
                                              step_rad=0.0, nozzle_radius=nozzle_radius,
                                              check=fine_outer)
                    left[sel[ok_t]] = False
                split = np.flatnonzero(left & (b_q - a_q >= 4))
                mid = (a_q[split] + b_q[split]) // 2
                rows_q = np.concatenate([rows_q[split], rows_q[split]])
                a_q, b_q = (np.concatenate([a_q[split], mid]),
                            np.concatenate([mid, b_q[split]]))
                if len(rows_q):
                    ok_h, _ = _sweep_segments(space, ids2, rows_q, a_q, b_q, n, j, base, g,
                                              verify=True, out=out, covered=covered,
                                              step_rad=0.0, nozzle_radius=nozzle_radius,
                                              check=fine_outer)
                    keep_q = ~ok_h & (b_q - a_q > 1)
                    rows_q, a_q, b_q = rows_q[keep_q], a_q[keep_q], b_q[keep_q]
        # a revolute group that failed is retried pairwise (its hull bulges more than
        # its pairs')
        if verify and kind != "prismatic" and len(bad):
            spans = b_a[bad] - a_a[bad]
            pr = np.repeat(rows_a[bad], spans)
            pa = np.concatenate([np.arange(a, b) for a, b in
                                 zip(a_a[bad].tolist(), b_a[bad].tolist(), strict=True)])
            _, exc = _sweep_segments(space, ids2, pr, pa, pa + 1, n, j, base, g, verify=True,
                                     out=out, covered=covered, step_rad=step_rad,
                                     nozzle_radius=nozzle_radius)
            excess = max(excess, exc)
    return out, excess, covered


def _sweep_segments(space: SampleSpace, ids2: np.ndarray, rows: np.ndarray, a: np.ndarray,
                    b: np.ndarray, n: int, j: int, base: _Pieces, g: BaseGeometry, *,
                    verify: bool, out: list[BaseGeometry], covered: np.ndarray,
                    step_rad: float, nozzle_radius: float,
                    check: tuple[np.ndarray, ...] | None = None) -> tuple[np.ndarray, float]:
    """Hull of the placements from sample a to sample b (indices mod n) of each row.

    Returns which segments were kept and the largest hull-versus-arc excess among the
    kept revolute ones (mm).
    """
    if not len(rows):
        return np.zeros(0, dtype=bool), 0.0
    kind = space.kinds[j]
    span = b - a
    flat_a = ids2[rows, a % n]
    flat_b = ids2[rows, b % n]
    phi_a, t_a = space.pose(space.joint_vectors(flat_a))
    phi_b, t_b = space.pose(space.joint_vectors(flat_b))
    ok = np.ones(len(rows), dtype=bool)
    seg_excess = np.zeros(len(rows))
    if kind != "prismatic":
        # the rotation's true radius (joint axis to the farthest nozzle point) per segment
        rho = _rotation_radius(phi_a, t_a, phi_b, t_b) + nozzle_radius
        theta = span * step_rad
        chord = {w: _chord_excess(w * step_rad) for w in np.unique(span).tolist()}
        seg_excess = rho * np.array([chord[w] for w in span.tolist()]) \
            + theta * base.shape_diameter / 4
        sag = rho * (1 - np.cos(theta / 2))
    else:
        sag = np.zeros(len(rows))
    if verify:
        moved = span > 0
        if moved.any():
            grow = float(sag[moved].max()) * 1.001

            def inside(polys: tuple[np.ndarray, ...], sel: np.ndarray) -> np.ndarray:
                if grow > 0:
                    polys = tuple(_ring(Polygon(c).buffer(grow, join_style="mitre",
                                                          mitre_limit=1e3))[:-1]
                                  for c in polys)
                res = np.ones(len(sel), dtype=bool)
                for coords in polys:
                    hull = _hulls([_placed(coords, phi_a[sel], t_a[sel]),
                                   _placed(coords, phi_b[sel], t_b[sel])])
                    res &= shapely.contains_properly(g, hull)
                return res

            # the coarse outer polygons contain the true orifice too: a hull that passes
            # with them is safe; only their failures are checked with the fine ones
            sel = np.flatnonzero(moved)
            res = inside(base.outer, sel)
            ok[sel] = res
            if check is not None and not res.all():
                again = sel[~res]
                ok[again] = inside(check, again)
        idx = np.flatnonzero(ok)
        for coords in base.inner:
            out.extend(_hulls([_placed(coords, phi_a[idx], t_a[idx]),
                               _placed(coords, phi_b[idx], t_b[idx])]).tolist())
    else:
        # outer bound: every placement of the group inside the hull (all of them for a
        # rotation, the two ends for a translation)
        for coords in base.outer:
            if kind == "prismatic" or span.max() <= 1:
                out.extend(_hulls([_placed(coords, phi_a, t_a),
                                   _placed(coords, phi_b, t_b)]).tolist())
                continue
            for width in np.unique(span).tolist():
                sel = np.flatnonzero(span == width)
                parts = []
                for s in range(width + 1):
                    f = ids2[rows[sel], (a[sel] + s) % n]
                    ph, tt = space.pose(space.joint_vectors(f))
                    parts.append(_placed(coords, ph, tt))
                out.extend(_hulls(parts).tolist())
    kept = np.flatnonzero(ok)
    if len(kept):
        lens = (b[kept] - a[kept] + 1).astype(np.int64)
        first = np.repeat(np.cumsum(lens) - lens, lens)
        cols = (np.repeat(a[kept], lens) + np.arange(int(lens.sum())) - first) % n
        covered.flat[ids2[np.repeat(rows[kept], lens), cols]] = True
    exc = float(seg_excess[ok].max()) if verify and ok.any() else 0.0
    return ok, exc


# --------------------------------------------------------------------------- components


def _components(space: SampleSpace, feasible: np.ndarray) -> tuple[int, np.ndarray]:
    """Label the connected components of the feasible samples (face neighbours, wraps)."""
    if not feasible.any():
        return 0, np.zeros(feasible.shape, dtype=np.int32)
    structure = ndimage.generate_binary_structure(feasible.ndim, 1)
    labels, count = ndimage.label(feasible, structure=structure)
    parent = list(range(count + 1))

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for j, wraps in enumerate(space.wrap):
        if not wraps:
            continue
        first = np.take(labels, 0, axis=j)
        last = np.take(labels, -1, axis=j)
        both = (first > 0) & (last > 0)
        for p, q in set(zip(first[both].tolist(), last[both].tolist(), strict=True)):
            rp, rq = find(p), find(q)
            if rp != rq:
                parent[max(rp, rq)] = min(rp, rq)
    roots = np.array([find(x) for x in range(count + 1)])
    merged = roots[labels]
    # renumber 0..n-1 in order of first appearance (flat C order); background -1
    flat = merged.ravel()
    nz = flat[flat > 0]
    _, first_idx = np.unique(nz, return_index=True)
    order = np.unique(nz)[np.argsort(first_idx)]
    remap = np.full(count + 1, -1, dtype=np.int32)
    remap[order] = np.arange(len(order), dtype=np.int32)
    return len(order), remap[merged]


# --------------------------------------------------------------------------- engine


def _draw_quad_segs(orifices: tuple[Orifice, ...], tolerance: float, most: int) -> int:
    """Fewest vertices per quarter keeping curved orifices' polygons within ``tolerance``.

    The polygons of a sweep cost union time in proportion to their vertices; the
    inner polygon of a curve of largest semi-axis a with n vertices is within
    a·(1 − cos(π/n)) of it, the outer within a·(1/cos(π/n) − 1).
    """
    a = max([max(o.semi_axes) for o in orifices if o.kind in ("circle", "ellipse")] or [0.0])
    if a <= 0:
        return most
    x = math.acos(1.0 / (1.0 + min(tolerance / a, 0.5)))
    return int(min(most, max(2, math.ceil(math.pi / x / 4))))



def _empty_result(g, nozzle, machine, space, notes, t0, resolution, angle_step):
    return MMCResult(
        engine="sampled", nozzle=nozzle, machine=machine, target=g, as_built=MultiPolygon(),
        target_area=float(g.area), as_built_area=0.0, lost_area=float(g.area),
        lost_area_bounds=(float(g.area), float(g.area)),
        motion=MotionRestriction(angles=np.zeros(0),
                                 samples=np.zeros((0, len(space.values)))),
        components=Components(count=0, geometries=(), angle_ranges=()),
        resolution=resolution, angle_step=angle_step, elapsed=time.perf_counter() - t0,
        notes=tuple(notes), extra={"samples": space.size,
                                   "feasible": np.zeros(space.shape, dtype=bool),
                                   "joint_names": space.names, "joint_values": space.values,
                                   "slack": space.slack})


def _chunks(space: SampleSpace, machine: Machine, nozzle: Nozzle, g: BaseGeometry):
    """Flat sample indices to test, in chunks, skipping first-joint values out of reach.

    For a chain, the axis of the second joint moves with the first one only; a value
    of the first joint whose second axis is farther from G's bounding box than the
    rest of the chain can reach (offsets, prismatic travels, tool, nozzle) cannot put
    the nozzle in G, whatever the other joints do.
    """
    n = space.size
    keep = np.ones(space.shape[0], dtype=bool)
    if machine.kind == "chain" and len(machine.joints) >= 2:
        joints = machine.joints
        head = replace(machine, joints=joints[:1], tool_offset=joints[1].offset,
                       tool_angle=0.0)
        _, centre = head.pose(space.values[0][:, None])
        rest = sum(math.hypot(*jj.offset) for jj in joints[2:])
        rest += sum(max(abs(jj.lo), abs(jj.hi)) for jj in joints[1:] if jj.kind == "prismatic")
        rest += math.hypot(*machine.tool_offset) + nozzle.radius
        # plus how far the axis moves within half a step of the first joint, so that
        # configurations between the skipped samples cannot reach G either
        rest += space.levers[0] * space.steps[0] / 2 + space.slack
        minx, miny, maxx, maxy = g.bounds
        dx = np.maximum(np.maximum(minx - centre[:, 0], centre[:, 0] - maxx), 0.0)
        dy = np.maximum(np.maximum(miny - centre[:, 1], centre[:, 1] - maxy), 0.0)
        keep = np.hypot(dx, dy) <= rest * (1 + 1e-9) + 1e-9
    block = n // space.shape[0]
    starts = np.flatnonzero(keep) * block
    if len(starts) == 0:
        return
    # merge consecutive kept blocks into ranges, then cut the ranges into chunks
    breaks = np.flatnonzero(np.diff(starts) != block) + 1
    for group in np.split(starts, breaks):
        lo, hi = int(group[0]), int(group[-1]) + block
        for c in range(lo, hi, _CHUNK):
            yield np.arange(c, min(hi, c + _CHUNK))


def mmc_sampled(
    region: BaseGeometry,
    nozzle: Nozzle,
    machine: Machine,
    *,
    settings: Settings = DEFAULT_SETTINGS,
    max_samples: int = DEFAULT_MAX_SAMPLES,
) -> MMCResult:
    """MMC of any machine by sampling its joint space and testing containment.

    Parameters
    ----------
    region
        G, a validated MultiPolygon, mm.
    nozzle
        The nozzle (every orifice must fit).
    machine
        Any machine: a chain (joints sampled at their own steps), or ``xy``/``ttr``
        (positions on a lattice of spacing ``settings.resolution``, angles from the
        machine's step or ``settings.angle_step``).
    settings
        ``chord_tolerance`` bounds the hull-versus-arc deviation of revolute sweeps;
        ``quad_segs`` sets the polygons of curved orifices; ``max_memory`` limits
        the working set.
    max_samples
        Refuse (ResourceError) above this many joint-space samples.

    Returns
    -------
    MMCResult
        ``motion.samples``: the feasible joint vectors (k, p); ``as_built``: S ⊆ G;
        ``extra["feasible"]``: the boolean feasibility grid over the joint values
        ``extra["joint_values"]``.

    Raises
    ------
    ResourceError
        Too many samples for ``max_samples`` or the memory limit.

    Notes
    -----
    See the module docstring for what S approximates and how the bounds are built.
    """
    t0 = time.perf_counter()
    g = region
    space = sample_space(g, nozzle, machine, settings=settings)
    orifices = orifices_of(nozzle, quad_segs=settings.quad_segs)
    n = space.size
    p = len(space.values)
    is_chain = machine.kind == "chain"
    resolution = space.slack if is_chain else float(settings.resolution)
    rot_steps = [s for s, k in zip(space.steps, space.kinds, strict=True) if k != "prismatic"]
    angle_step = max(rot_steps) if rot_steps and (is_chain or space.levers[-1] > 0) else 0.0
    describe = ", ".join(f"{nm}: {len(v):,} values" for nm, v in
                         zip(space.names, space.values, strict=True))
    memory = n * (2 + 4 + 8 * p) + _CHUNK * (16 * p + 64 * len(orifices) + 64)
    if n > max_samples or memory > settings.max_memory:
        raise ResourceError(
            f"the sampled engine would test {n:,} configurations of machine {machine.name!r} "
            f"({describe}) needing about {memory / 2**20:,.0f} MiB; the limits are "
            f"{max_samples:,} configurations and {settings.max_memory / 2**20:,.0f} MiB: use "
            "coarser joint steps in the machine profile (or a coarser resolution / angle "
            "step on xy and ttr machines), or narrow the joint ranges to the part"
        )
    notes: list[str] = []
    if n == 0:
        notes.append("the nozzle does not fit in the region's bounding box at any sampled "
                     "angle: nothing can be printed")
        return _empty_result(g, nozzle, machine, space, notes, t0, resolution, angle_step)

    shapely.prepare(g)
    slack = space.slack
    reach_max = max(o.circumradius + math.hypot(*o.center) for o in orifices)
    edges = boundary_edges(g, max(reach_max / 2, 1e-3))
    feasible_tests = [containment_test(o, 0.0, closed=True) for o in orifices]
    r_in_min = min(o.inradius for o in orifices)
    has_outer = slack * 1.01 < r_in_min
    opt_tests = [containment_test(o, slack, closed=False) for o in orifices] if has_outer else []
    if has_outer and any(tt.empty for tt in opt_tests):
        has_outer = False
    if not has_outer:
        notes.append(
            f"a configuration can be {slack:.3g} mm (every nozzle point) away from the nearest "
            f"sample, more than the nozzle's inscribed radius {r_in_min:.3g} mm: no lower "
            "bound on the lost area (reported as 0); use finer joint steps"
        )

    feasible = np.zeros(n, dtype=bool)
    optimistic = np.zeros(n, dtype=bool)
    over_part = 0  # samples with the first orifice's centre over G
    # samples whose nozzle, grown by the slack, reaches G's bounding box: with none, no
    # configuration at all (sampled or not) can print anything
    near = 0
    minx, miny, maxx, maxy = g.bounds
    margin = nozzle.radius + slack
    for flat in _chunks(space, machine, nozzle, g):
        phi, t = space.pose(space.joint_vectors(flat))
        near += int(np.count_nonzero((t[:, 0] >= minx - margin) & (t[:, 0] <= maxx + margin)
                                     & (t[:, 1] >= miny - margin) & (t[:, 1] <= maxy + margin)))
        ok = np.ones(len(flat), dtype=bool)
        for k, (test, o) in enumerate(zip(feasible_tests, orifices, strict=True)):
            res, n_over = run_containment_test(test, o.center, g, edges, phi, t, ok)
            ok &= res
            over_part += n_over if k == 0 else 0
        feasible[flat] = ok
        if has_outer:
            oo = np.ones(len(flat), dtype=bool)
            for test, o in zip(opt_tests, orifices, strict=True):
                oo &= run_containment_test(test, o.center, g, edges, phi, t, oo)[0]
            optimistic[flat] = oo | ok
    feasible = feasible.reshape(space.shape)
    optimistic = optimistic.reshape(space.shape)
    n_feasible = int(feasible.sum())
    if over_part == 0:
        notes.append(f"no configuration of machine {machine.name!r} puts the nozzle over the "
                     "part: it is out of the machine's reach")

    # ---- S: sweeps along every joint of a chain; on the xy/ttr lattice, whose step is
    # far below the nozzle size, along X only (neighbouring rows overlap; what is left
    # between their ends is a scallop of depth ~h²/(8r), and the bounds account for it)
    tol = float(settings.chord_tolerance)
    axes = [j for j, k in enumerate(space.kinds) if k != "spin"] if is_chain else [0]
    draw = orifices_of(nozzle, quad_segs=_draw_quad_segs(orifices, tol, settings.quad_segs))
    polys, excess, covered = _sweep(space, feasible, draw, orifices, nozzle.radius, g,
                                    tolerance=tol, axes=axes, verify=True)
    lonely = np.flatnonzero((feasible & ~covered).ravel())
    if len(lonely):
        phi, t = space.pose(space.joint_vectors(lonely))
        for o in draw:
            for piece in o.inner_pieces:
                polys.extend(shapely.polygons(_placed(_ring(piece), phi, t)).tolist())
    as_built = shapely.union_all(polys) if polys else MultiPolygon()
    target_area = float(g.area)
    as_built_area = float(as_built.area)
    lost = max(0.0, target_area - as_built_area)
    hi = min(target_area, lost + 2 * excess * float(as_built.length))
    if has_outer and optimistic.any():
        # one joint suffices to cover every optimistic sample: prefer a prismatic one
        order = sorted(axes, key=lambda j: (space.kinds[j] != "prismatic", -space.shape[j]))
        axis = order[0] if order else 0
        o_polys, _, _ = _sweep(space, optimistic, draw, draw, nozzle.radius, g,
                               tolerance=tol, axes=[axis], verify=False, grow=slack)
        outer = shapely.union_all(o_polys)
        lo_b = max(0.0, target_area - float(shapely.intersection(outer, g).area))
    elif has_outer or near == 0:
        lo_b = target_area
    else:
        lo_b = 0.0
    lo_b = min(lo_b, lost)

    # ---- P, components
    samples_flat = np.flatnonzero(feasible.ravel())
    samples = space.joint_vectors(samples_flat) if len(samples_flat) else np.zeros((0, p))
    phi_f, t_f = space.pose(samples) if len(samples) else (np.zeros(0), np.zeros((0, 2)))
    count, labels = _components(space, feasible)
    lab_f = labels.ravel()[samples_flat]
    geoms: list[BaseGeometry] = []
    ranges: list[tuple[float, float]] = []
    for c_id in range(count):
        sel = lab_f == c_id
        ranges.append((float(phi_f[sel].min()), float(phi_f[sel].max())))
        if is_chain:
            if n_feasible <= _MAX_COMPONENT_POINTS:
                geoms.append(shapely.multipoints(t_f[sel]))
        else:
            # the lattice cells of its positions (any angle), merged into rectangles
            mask = labels == c_id
            if mask.ndim == 3:
                mask = mask.any(axis=2)
            rects = grid_rectangles(mask.T, space.values[0], space.values[1],
                                    float(settings.resolution))
            geoms.append(shapely.union_all(shapely.box(*rects.T)))
    components = Components(
        count=count,
        geometries=tuple(geoms) if len(geoms) == count else None,
        angle_ranges=tuple(ranges),
    )
    if is_chain:
        angles = np.unique(np.round(np.mod(phi_f, 360.0), 9))
    else:
        angles = space.values[2] if p > 2 else np.array([0.0])
    steps = ", ".join(f"{nm} every {st:g}" for nm, st in
                      zip(space.names, space.steps, strict=True))
    notes.insert(0, (
        f"sampled: {n:,} configurations ({describe}; {steps}), {n_feasible:,} feasible; every "
        f"configuration is within {slack:.3g} mm (any nozzle point) of a sample; S sweeps "
        f"hulls between consecutive feasible samples (revolute sweeps within {excess:.2g} mm "
        "of the true arcs)"
    ))
    return MMCResult(
        engine="sampled",
        nozzle=nozzle,
        machine=machine,
        target=g,
        as_built=as_built,
        target_area=target_area,
        as_built_area=as_built_area,
        lost_area=lost,
        lost_area_bounds=(lo_b, hi),
        motion=MotionRestriction(angles=np.asarray(angles, dtype=float), samples=samples),
        components=components,
        resolution=resolution,
        angle_step=angle_step,
        elapsed=time.perf_counter() - t0,
        notes=tuple(notes),
        extra={"samples": n, "feasible": feasible, "optimistic": int(optimistic.sum()),
               "joint_names": space.names, "joint_values": space.values, "slack": slack,
               "sweep_excess": excess, "component_labels": labels},
    )

"""Sweeps of the sampled engine: S from the feasible samples, for :mod:`printability.mmc.sampled`.

S = the union of the footprints swept between consecutive feasible samples
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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from printability.mmc._sample_space import SampleSpace, placed, ring_coords
from printability.mmc.orifices import Orifice

__all__ = ["sweep"]


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
    inner = tuple(ring_coords(p)[:-1] for o in orifices for p in o.inner_pieces)
    outs = []
    for o in orifices:
        for p in o.outer_pieces:
            q = p.buffer(grow, join_style="mitre", mitre_limit=1e3) if grow > 0 else p
            outs.append(ring_coords(q)[:-1])
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


def sweep(
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
                z = np.zeros(len(seg), dtype=np.int64)
                axis = _Axis(space, flat_ids.reshape(-1, 1), 1, j, base, g, nozzle_radius, out,
                             covered)
                _sweep_segments(axis, seg, z, z, verify=False, step_rad=0.0)
            continue
        axis = _Axis(space, np.moveaxis(flat_ids, j, -1).reshape(-1, n), n, j, base, g,
                     nozzle_radius, out, covered)
        m2 = np.moveaxis(mask, j, -1).reshape(-1, n)
        excess = max(excess, _sweep_axis(axis, m2, tolerance, verify, fine_outer))
    return out, excess, covered


@dataclass(frozen=True, eq=False)
class _Axis:
    """The sweep along joint ``j``: the samples' flat ids as rows of ``n`` values of the
    joint (``ids2``), the pieces swept, G, and where kept polygons (``out``) and the
    samples they cover (``covered``) are recorded."""

    space: SampleSpace
    ids2: np.ndarray
    n: int
    j: int
    base: _Pieces
    g: BaseGeometry
    nozzle_radius: float
    out: list[BaseGeometry]
    covered: np.ndarray


def _sweep_axis(axis: _Axis, m2: np.ndarray, tolerance: float, verify: bool,
                fine_outer: tuple[np.ndarray, ...]) -> float:
    """Sweep the runs of ``m2`` (rows × n) along one joint; the largest revolute excess."""
    space, n, j = axis.space, axis.n, axis.j
    kind = space.kinds[j]
    rows, starts, lengths = _runs(m2, space.wrap[j])
    if not len(rows):
        return 0.0
    step_rad = math.radians(space.steps[j]) if kind != "prismatic" else 0.0
    reach = space.reaches[j]
    if kind == "prismatic":
        group = max(int(lengths.max()) - 1, 1)
    else:
        group = 1
        while group < n and (reach * _chord_excess((group + 1) * step_rad)
                             + (group + 1) * step_rad * axis.base.shape_diameter / 4
                             ) <= tolerance:
            group += 1
    rows_a, a_a, b_a = _groups(rows, starts, lengths, group, n, space.wrap[j])
    kept, excess = _sweep_segments(axis, rows_a, a_a, b_a, verify=verify, step_rad=step_rad,
                                   check=fine_outer if kind == "prismatic" else None)
    bad = np.flatnonzero(~kept & (b_a - a_a > 1))
    if verify and kind == "prismatic":
        _retry_translations(axis, rows_a[bad], a_a[bad], b_a[bad], fine_outer)
    # a revolute group that failed is retried pairwise (its hull bulges more than
    # its pairs')
    if verify and kind != "prismatic" and len(bad):
        spans = b_a[bad] - a_a[bad]
        pr = np.repeat(rows_a[bad], spans)
        pa = np.concatenate([np.arange(a, b) for a, b in
                             zip(a_a[bad].tolist(), b_a[bad].tolist(), strict=True)])
        _, exc = _sweep_segments(axis, pr, pa, pa + 1, verify=True, step_rad=step_rad)
        excess = max(excess, exc)
    return excess


def _groups(rows: np.ndarray, starts: np.ndarray, lengths: np.ndarray, group: int, n: int,
            closed: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Runs cut into groups of at most ``group`` steps: (row, first, last sample) each;
    with ``closed`` a run of the whole row is a full turn that closes on itself."""
    seg_rows, seg_a, seg_b = [], [], []
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
    return (np.asarray(seg_rows, dtype=np.int64), np.asarray(seg_a, dtype=np.int64),
            np.asarray(seg_b, dtype=np.int64))


def _retry_translations(axis: _Axis, rows_q: np.ndarray, a_q: np.ndarray, b_q: np.ndarray,
                        fine_outer: tuple[np.ndarray, ...]) -> None:
    """Retry translation runs whose hull failed.

    A translation's hull is its exact sweep: it fails because some placement grazes
    ∂G, most often an end of the run. Try the run without its first and/or last
    sample, then halves, down to single steps.
    """
    while len(rows_q):
        tries = [(a_q, b_q - 1), (a_q + 1, b_q), (a_q + 1, b_q - 1)]
        left = np.ones(len(rows_q), dtype=bool)
        for ta, tb in tries:
            sel = np.flatnonzero(left & (tb - ta >= 1))
            if not len(sel):
                continue
            ok_t, _ = _sweep_segments(axis, rows_q[sel], ta[sel], tb[sel], verify=True,
                                      step_rad=0.0, check=fine_outer)
            left[sel[ok_t]] = False
        split = np.flatnonzero(left & (b_q - a_q >= 4))
        mid = (a_q[split] + b_q[split]) // 2
        rows_q = np.concatenate([rows_q[split], rows_q[split]])
        a_q, b_q = (np.concatenate([a_q[split], mid]),
                    np.concatenate([mid, b_q[split]]))
        if len(rows_q):
            ok_h, _ = _sweep_segments(axis, rows_q, a_q, b_q, verify=True, step_rad=0.0,
                                      check=fine_outer)
            keep_q = ~ok_h & (b_q - a_q > 1)
            rows_q, a_q, b_q = rows_q[keep_q], a_q[keep_q], b_q[keep_q]


def _sweep_segments(axis: _Axis, rows: np.ndarray, a: np.ndarray, b: np.ndarray, *,
                    verify: bool, step_rad: float,
                    check: tuple[np.ndarray, ...] | None = None) -> tuple[np.ndarray, float]:
    """Hull of the placements from sample a to sample b (indices mod n) of each row.

    Returns which segments were kept and the largest hull-versus-arc excess among the
    kept revolute ones (mm).
    """
    if not len(rows):
        return np.zeros(0, dtype=bool), 0.0
    space, ids2, n, base = axis.space, axis.ids2, axis.n, axis.base
    kind = space.kinds[axis.j]
    span = b - a
    flat_a = ids2[rows, a % n]
    flat_b = ids2[rows, b % n]
    phi_a, t_a = space.pose(space.joint_vectors(flat_a))
    phi_b, t_b = space.pose(space.joint_vectors(flat_b))
    ok = np.ones(len(rows), dtype=bool)
    seg_excess = np.zeros(len(rows))
    if kind != "prismatic":
        # the rotation's true radius (joint axis to the farthest nozzle point) per segment
        rho = _rotation_radius(phi_a, t_a, phi_b, t_b) + axis.nozzle_radius
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
                    polys = tuple(ring_coords(Polygon(c).buffer(grow, join_style="mitre",
                                                                mitre_limit=1e3))[:-1]
                                  for c in polys)
                res = np.ones(len(sel), dtype=bool)
                for coords in polys:
                    hull = _hulls([placed(coords, phi_a[sel], t_a[sel]),
                                   placed(coords, phi_b[sel], t_b[sel])])
                    res &= shapely.contains_properly(axis.g, hull)
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
            axis.out.extend(_hulls([placed(coords, phi_a[idx], t_a[idx]),
                                    placed(coords, phi_b[idx], t_b[idx])]).tolist())
    else:
        _outer_hulls(axis, rows, a, span, phi_a, t_a, phi_b, t_b)
    kept = np.flatnonzero(ok)
    if len(kept):
        lens = (b[kept] - a[kept] + 1).astype(np.int64)
        first = np.repeat(np.cumsum(lens) - lens, lens)
        cols = (np.repeat(a[kept], lens) + np.arange(int(lens.sum())) - first) % n
        axis.covered.flat[ids2[np.repeat(rows[kept], lens), cols]] = True
    exc = float(seg_excess[ok].max()) if verify and ok.any() else 0.0
    return ok, exc


def _outer_hulls(axis: _Axis, rows: np.ndarray, a: np.ndarray, span: np.ndarray,
                 phi_a: np.ndarray, t_a: np.ndarray, phi_b: np.ndarray,
                 t_b: np.ndarray) -> None:
    """The outer bound's hulls: every placement of a group inside its hull (all of them
    for a rotation, the two ends (φ_a, t_a), (φ_b, t_b) for a translation)."""
    space, ids2, n = axis.space, axis.ids2, axis.n
    for coords in axis.base.outer:
        if space.kinds[axis.j] == "prismatic" or span.max() <= 1:
            axis.out.extend(_hulls([placed(coords, phi_a, t_a),
                                    placed(coords, phi_b, t_b)]).tolist())
            continue
        for width in np.unique(span).tolist():
            sel = np.flatnonzero(span == width)
            parts = []
            for s in range(width + 1):
                f = ids2[rows[sel], (a[sel] + s) % n]
                ph, tt = space.pose(space.joint_vectors(f))
                parts.append(placed(coords, ph, tt))
            axis.out.extend(_hulls(parts).tolist())

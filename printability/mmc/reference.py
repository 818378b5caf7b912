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
import shapely.affinity
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.base import BaseGeometry

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.errors import InputError, ResourceError
from printability.geometry import polygons_of, rotation_matrix
from printability.machine import Machine
from printability.mmc.components import angle_ranges, component_labels
from printability.mmc.result import Components, MMCResult, MotionRestriction
from printability.nozzle import Nozzle
from printability.settings import DEFAULT_SETTINGS, Settings

_guard_kernel_caches()  # the cache check runs before a kernel here loads

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

# GEOS buffers approximate arcs by inscribed chords; dividing an offset by this factor
# makes a grown polygon contain (a shrunk one lie inside) the true offset set.
_ARC_QUAD_SEGS = 8
_ARC_FACTOR = 1.0 / math.cos(math.pi / (4 * _ARC_QUAD_SEGS))


# --------------------------------------------------------------------------- footprints


@dataclass(frozen=True, eq=False)
class Orifice:
    """One orifice in the nozzle frame (mounting angle applied), with safe approximations.

    Attributes
    ----------
    inner, outer
        Polygons inside / containing the true orifice (equal for rectangles and
        polygons; curved orifices differ by about a·π²/(2n²) mm).
    inner_pieces, outer_pieces
        Convex pieces whose union is ``inner`` / ``outer`` (the polygon itself
        when convex, else a constrained triangulation).
    center, inradius
        A disk of that centre and radius (mm) lies inside ``inner``.
    circumradius
        Largest distance from ``center`` to ``outer``, mm.
    disk
        ``(cx, cy, r)`` when the orifice is an exact circle (tests are then exact).
    diameter
        Largest distance between two points of ``outer``, mm.
    kind, semi_axes, frame_angle
        The exact shape: kind of :class:`~printability.nozzle.Footprint`; semi-axes
        (a, b) of a circle/ellipse/rectangle centred on ``center`` and turned by
        ``frame_angle`` degrees in the nozzle frame (unused for polygons).
    """

    inner: Polygon
    outer: Polygon
    inner_pieces: tuple[Polygon, ...]
    outer_pieces: tuple[Polygon, ...]
    center: tuple[float, float]
    inradius: float
    circumradius: float
    disk: tuple[float, float, float] | None
    diameter: float
    kind: str = "polygon"
    semi_axes: tuple[float, float] = (0.0, 0.0)
    frame_angle: float = 0.0


def _convex_pieces(poly: Polygon) -> tuple[Polygon, ...]:
    hull = poly.convex_hull
    if poly.area >= hull.area * (1.0 - 1e-12):
        return (poly,)
    return tuple(polygons_of(shapely.constrained_delaunay_triangles(poly)))


def orifices_of(nozzle: Nozzle, *, quad_segs: int) -> tuple[Orifice, ...]:
    """The orifices of ``nozzle`` with inner/outer polygons and inscribed disks.

    Parameters
    ----------
    nozzle
        The nozzle; its mounting angle is applied.
    quad_segs
        Vertices per quarter of a curved orifice.
    """
    out = []
    mount = nozzle.mount_angle
    rot = rotation_matrix(mount)
    for f in nozzle.footprints:
        inner = f.polygon(quad_segs=quad_segs, mode="inner")
        outer = f.polygon(quad_segs=quad_segs, mode="outer")
        if mount % 360.0:
            inner = shapely.affinity.rotate(inner, mount, origin=(0.0, 0.0))
            outer = shapely.affinity.rotate(outer, mount, origin=(0.0, 0.0))
        n = len(inner.exterior.coords) - 1
        disk = None
        if f.kind in ("circle", "ellipse", "rect"):
            c = tuple(float(v) for v in rot @ np.asarray(f.center))
            if f.kind == "rect":
                r_in = min(f.a, f.b)
            else:
                # the inscribed n-gon is the affine image of a regular n-gon, which holds
                # the disk of radius cos(π/n)
                r_in = min(f.a, f.b) * math.cos(math.pi / n)
            if f.kind == "circle":
                disk = (c[0], c[1], f.a)
        else:
            line = shapely.maximum_inscribed_circle(inner)
            (x0, y0), _ = line.coords
            c, r_in = (float(x0), float(y0)), float(line.length)
        pts = np.asarray(outer.exterior.coords)
        circum = float(np.max(np.hypot(pts[:, 0] - c[0], pts[:, 1] - c[1])))
        diff = pts[:, None, :] - pts[None, :, :]
        diameter = float(np.sqrt((diff**2).sum(-1).max()))
        out.append(Orifice(inner, outer, _convex_pieces(inner), _convex_pieces(outer),
                           c, r_in, circum, disk, diameter, f.kind, (f.a, f.b),
                           mount + f.rotation))
    return tuple(out)


def angle_gap(machine: Machine, angles: np.ndarray, period: float) -> tuple[float, bool]:
    """Largest gap between consecutive sampled angles (degrees) and whether they wrap.

    They wrap when the samples cover a whole symmetry period (full-turn machine or
    a range at least one period wide), so the last angle neighbours the first.
    """
    if len(angles) <= 1:
        return 0.0, False
    gaps = np.diff(angles)
    span = machine.angle_max - machine.angle_min
    wrap = machine.full_turn or (0 < period < 360.0 and span >= period - 1e-9)
    if wrap:
        gaps = np.append(gaps, angles[0] + min(period, 360.0) - angles[-1])
    return float(gaps.max()), bool(wrap)


def grid_rectangles(mask: np.ndarray, xs: np.ndarray, ys: np.ndarray, h: float) -> np.ndarray:
    """Cover the lattice cells of the True entries of ``mask[iy, ix]`` by few rectangles.

    Each True entry stands for the square of side ``h`` centred on (xs[ix], ys[iy]).
    Runs along rows are merged, then identical runs of consecutive rows.

    Returns
    -------
    ndarray (k, 4)
        Rectangles ``(x0, y0, x1, y1)``, mm.
    """
    rects: list[list[float]] = []
    open_runs: dict[tuple[int, int], int] = {}
    half = 0.5 * h
    for iy in range(mask.shape[0]):
        row = mask[iy]
        if not row.any():
            open_runs = {}
            continue
        d = np.diff(np.concatenate([[0], row.astype(np.int8), [0]]))
        starts = np.flatnonzero(d == 1)
        ends = np.flatnonzero(d == -1) - 1
        new_runs: dict[tuple[int, int], int] = {}
        for a, b in zip(starts.tolist(), ends.tolist(), strict=True):
            k = open_runs.get((a, b))
            if k is not None:
                rects[k][3] = ys[iy] + half
            else:
                k = len(rects)
                rects.append([xs[a] - half, ys[iy] - half, xs[b] + half, ys[iy] + half])
            new_runs[(a, b)] = k
        open_runs = new_runs
    return np.asarray(rects, dtype=float).reshape(-1, 4)


def cell_footprint_union(
    rects: np.ndarray, pieces: tuple[Polygon, ...], angle: float, *, grow: float = 0.0
) -> list[BaseGeometry]:
    """Polygons whose union is ∪_rect rect ⊕ R(angle)·(∪ pieces ⊕ D(grow)).

    Each rectangle ⊕ convex piece is the convex hull of the piece placed at the four
    corners (exact for convex pieces). ``grow`` > 0 buffers each piece first
    (enlarged so the chords of the buffer stay outside the true offset).
    """
    if len(rects) == 0:
        return []
    out: list[BaseGeometry] = []
    rot = rotation_matrix(angle)
    corners = np.stack([rects[:, [0, 1]], rects[:, [2, 1]], rects[:, [2, 3]],
                        rects[:, [0, 3]]], axis=1)  # (k, 4, 2)
    for piece in pieces:
        if grow > 0:
            piece = piece.buffer(grow * _ARC_FACTOR, quad_segs=_ARC_QUAD_SEGS)
        v = np.asarray(piece.exterior.coords)[:-1] @ rot.T  # (nv, 2)
        pts = (corners[:, :, None, :] + v[None, None, :, :]).reshape(len(rects), -1, 2)
        out.extend(shapely.convex_hull(shapely.linestrings(pts)).tolist())
    return out


# --------------------------------------------------------------------------- numba kernel


@numba.njit(cache=True)
def _mark_inverse_trajectories(px, py, kind, dcx, dcy, dr, ex0, ey0, ex1, ey1, ymin, ymax,
                               strict, h, ix0, iy0, diff, xs):  # pragma: no cover
    """Rasterise the inverse trajectories of sample points onto the position lattice.

    At a fixed angle φ the inverse trajectory of a point Y meets the (turned) test
    shape F exactly at the positions t ∈ Y − F. For every sample Y and every lattice
    row, the row's intersection with Y − F is a set of intervals (even-odd rule over
    F's edges, or the chord of a disk); each interval adds +1/−1 to the row's
    difference array ``diff`` so that, after a cumulative sum, a lattice point is
    covered when some sample's inverse trajectory reaches it.
    """
    ny = diff.shape[0]
    nx = diff.shape[1] - 1
    for m in range(len(px)):
        yx = px[m]
        yy = py[m]
        j0 = max(math.ceil((yy - ymax) / h), iy0)
        j1 = min(math.floor((yy - ymin) / h), iy0 + ny - 1)
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


# --------------------------------------------------------------------------- sampling


def _boundary_samples(g: BaseGeometry, spacing: float) -> np.ndarray:
    """Points on every ring of ``g``, at most ``spacing`` apart along the ring."""
    out = []
    for poly in polygons_of(g):
        for ring in (poly.exterior, *poly.interiors):
            n = max(3, math.ceil(ring.length / spacing))
            d = np.arange(n) * (ring.length / n)
            out.append(shapely.get_coordinates(shapely.line_interpolate_point(ring, d)))
    return np.concatenate(out) if out else np.zeros((0, 2))


def _interior_samples(g: BaseGeometry, spacing: float) -> np.ndarray:
    """Lattice points of spacing ``spacing`` strictly inside ``g``."""
    minx, miny, maxx, maxy = g.bounds
    xs = np.arange(math.floor(minx / spacing), math.ceil(maxx / spacing) + 1) * spacing
    ys = np.arange(math.floor(miny / spacing), math.ceil(maxy / spacing) + 1) * spacing
    gx, gy = np.meshgrid(xs, ys)
    gx, gy = gx.ravel(), gy.ravel()
    shapely.prepare(g)
    keep = shapely.contains_xy(g, gx, gy)
    return np.column_stack([gx[keep], gy[keep]])


@dataclass(frozen=True, eq=False)
class _TestShape:
    """A shape in the nozzle frame that samples are tested against.

    Either a disk (``disk`` = (cx, cy, r), empty when r <= 0) or polygon edges
    ``edges`` (k, 4) = (x0, y0, x1, y1) of every ring (even-odd rule).
    """

    disk: tuple[float, float, float] | None
    edges: np.ndarray
    strict: bool

    def turned(self, angle: float) -> tuple:
        """Kernel arguments of the shape turned by ``angle`` degrees."""
        rot = rotation_matrix(angle)
        if self.disk is not None:
            cx, cy = rot @ np.asarray(self.disk[:2])
            r = self.disk[2]
            e = np.zeros((0, 4))
            return (0, float(cx), float(cy), float(r), e[:, 0], e[:, 1], e[:, 2], e[:, 3],
                    float(cy - r), float(cy + r))
        a = self.edges[:, :2] @ rot.T
        b = self.edges[:, 2:] @ rot.T
        ys = np.concatenate([a[:, 1], b[:, 1]])
        return (1, 0.0, 0.0, 0.0, np.ascontiguousarray(a[:, 0]), np.ascontiguousarray(a[:, 1]),
                np.ascontiguousarray(b[:, 0]), np.ascontiguousarray(b[:, 1]),
                float(ys.min()), float(ys.max()))

    @property
    def empty(self) -> bool:
        return (self.disk[2] <= 0) if self.disk is not None else len(self.edges) == 0

    @property
    def height(self) -> float:
        if self.disk is not None:
            return 2 * max(self.disk[2], 0.0)
        return float(np.ptp(self.edges[:, [1, 3]])) if len(self.edges) else 0.0

    @property
    def cost(self) -> int:
        """Edges visited per lattice row."""
        return 1 if self.disk is not None else max(1, len(self.edges))


def offset_orifice(o: Orifice, base: str, offset: float) -> BaseGeometry:
    """The orifice's ``base`` ("inner" or "outer") polygon offset by ``offset`` mm.

    Outward (``offset`` > 0) the result contains the true offset set, inward it lies
    inside the true erosion: convex polygons use mitred joins (exact inward, a
    superset by offset·(sec(θ/2) − 1) at a vertex of exterior angle θ outward);
    other polygons use round joins with the radius enlarged so the chords of the
    arcs stay on the safe side. May be empty when shrunk.
    """
    poly = o.inner if base == "inner" else o.outer
    if not offset:
        return poly
    convex = len(o.inner_pieces if base == "inner" else o.outer_pieces) == 1
    if convex:
        return poly.buffer(offset, join_style="mitre", mitre_limit=1e3)
    return poly.buffer(offset * _ARC_FACTOR, quad_segs=_ARC_QUAD_SEGS)


def _test_shape(o: Orifice, base: str, offset: float, *, strict: bool) -> _TestShape:
    """The orifice's inner or outer polygon offset by ``offset`` mm (> 0 out, < 0 in).

    See :func:`offset_orifice`; a circle is offset exactly.
    """
    if o.disk is not None:
        return _TestShape((o.disk[0], o.disk[1], o.disk[2] + offset), np.zeros((0, 4)), strict)
    poly = offset_orifice(o, base, offset)
    edges = []
    for part in polygons_of(poly):
        for ring in (part.exterior, *part.interiors):
            c = np.asarray(ring.coords)
            edges.append(np.column_stack([c[:-1], c[1:]]))
    return _TestShape(None, np.concatenate(edges) if edges else np.zeros((0, 4)), strict)


def _windows(g: BaseGeometry, orifices: tuple[Orifice, ...], angles: np.ndarray, h: float,
             pad: float) -> list[tuple[int, int, int, int]]:
    """Per angle, the lattice index window of t with R(φ)A + t inside bbox(G) (± pad)."""
    gminx, gminy, gmaxx, gmaxy = g.bounds
    pts = np.concatenate([np.asarray(o.outer.exterior.coords) for o in orifices])
    out = []
    for a in angles:
        p = pts @ rotation_matrix(float(a)).T
        lo_x = gminx - p[:, 0].min() - pad
        hi_x = gmaxx - p[:, 0].max() + pad
        lo_y = gminy - p[:, 1].min() - pad
        hi_y = gmaxy - p[:, 1].max() + pad
        out.append((math.ceil(lo_x / h), math.floor(hi_x / h),
                    math.ceil(lo_y / h), math.floor(hi_y / h)))
    return out


# --------------------------------------------------------------------------- engine


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
        G, a validated MultiPolygon (see :func:`printability.geometry.as_region`), mm.
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
    if not machine.separable:
        raise InputError(f"the reference engine needs a separable machine (xy or ttr); "
                         f"machine {machine.name!r} is a joint chain: use the sampled engine")
    g = region
    h = float(settings.resolution)
    delta = h / 2 if boundary_spacing is None else float(boundary_spacing)
    if not (delta > 0) or not math.isfinite(delta):
        raise InputError(f"boundary_spacing must be a positive length in mm; got {delta!r}")
    period = nozzle.symmetry_period
    angles = np.asarray(machine.angles(step=settings.angle_step, period=period), dtype=float)
    gap, wrap = angle_gap(machine, angles, period)
    turning = machine.turns(nozzle) and len(angles) > 1
    orifices = orifices_of(nozzle, quad_segs=settings.quad_segs)
    r_in = min(o.inradius for o in orifices)
    r_max = nozzle.radius
    rho = h / math.sqrt(2.0)
    eps = rho + delta / 2  # grow for the conservative B test
    spin = r_max * math.radians(gap / 2) if turning else 0.0
    rho_out = rho + spin  # shrink for the optimistic pass
    notes: list[str] = []
    if r_in <= 0:
        raise InputError(f"nozzle {nozzle.spec!r}: an orifice has no inscribed disk")
    has_outer = r_in - rho_out > 1e-9 * max(1.0, r_in)
    if has_outer:
        q_spacing = 0.95 * math.sqrt(2.0) * (r_in - rho_out)
    else:
        q_spacing = 0.95 * math.sqrt(2.0) * r_in
        notes.append(
            f"the lattice cell (h = {h:g} mm) and angular gap ({gap:g}°) move the nozzle by "
            f"{rho_out:.3g} mm, more than its inscribed radius {r_in:.3g} mm: no lower bound "
            "on the lost area (reported as 0); use a finer resolution or angle step"
        )

    # ---- test shapes: per orifice, C (an interior sample inside it), B (a boundary sample
    # within ε of it), and the optimistic pass's C' = B' (inside it shrunk by ρ').
    n_o = len(orifices)
    c_in = [_test_shape(o, "inner", 0.0, strict=True) for o in orifices]
    b_in = [_test_shape(o, "outer", eps, strict=False) for o in orifices]
    c_out = [_test_shape(o, "inner", -rho_out, strict=False) for o in orifices]
    b_out = [_test_shape(o, "inner", -rho_out, strict=True) for o in orifices]

    # ---- work estimate, before any heavy allocation
    windows = _windows(g, orifices, angles, h, pad=0.0)
    windows_out = _windows(g, orifices, angles, h, pad=rho_out + h)
    n_t = sum(max(0, b - a + 1) * max(0, d - c + 1) for a, b, c, d in windows)
    n_t_out = sum(max(0, b - a + 1) * max(0, d - c + 1) for a, b, c, d in windows_out)
    n_boundary = sum(max(3, math.ceil(r.length / delta)) for p in polygons_of(g)
                     for r in (p.exterior, *p.interiors))
    n_interior = int(g.area / q_spacing**2) + 1

    def shape_work(shapes: list[_TestShape], n_samples: int) -> float:
        return sum(n_samples * (s.height / h + 1) * s.cost for s in shapes)

    def live(wins: list[tuple[int, int, int, int]]) -> int:
        return sum(1 for a, b, c, d in wins if b >= a and d >= c)

    work = live(windows) * (shape_work(c_in, n_interior) + shape_work(b_in, n_boundary))
    if has_outer:
        work += live(windows_out) * (shape_work(c_out, n_interior)
                                     + shape_work(b_out, n_boundary))
    work += 4 * n_o * (n_t + n_t_out)
    memory = 16 * (n_boundary + n_interior) + 24 * max(
        [max(0, b - a + 2) * max(0, d - c + 1) for a, b, c, d in windows_out] or [0])
    if work > max_work or memory > settings.max_memory:
        raise ResourceError(
            f"the reference engine would need about {work:.2g} operations and "
            f"{memory / 2**20:.3g} MiB ({n_t + n_t_out:,} positions over {len(angles)} "
            f"angle(s), {n_boundary:,} boundary and {n_interior:,} interior samples), more "
            f"than its budget of {max_work:.2g} operations and {settings.max_memory / 2**20:.3g}"
            f" MiB; it is meant for small checks: use a coarser resolution (now {h:g} mm), a "
            f"larger angle step, a smaller region, or the exact/raster engines"
        )

    # ---- samples of G and ∂G
    q_pts = _interior_samples(g, q_spacing)
    y_pts = _boundary_samples(g, delta)
    xs_buf = np.zeros(max([len(s.edges) for s in (*b_in, *c_in, *c_out)] + [2]) + 2)

    def covered(shape: _TestShape, pts: np.ndarray, win: tuple[int, int, int, int],
                angle: float) -> np.ndarray:
        """Lattice positions of ``win`` reached by the inverse trajectory of some point."""
        ix0, ix1, iy0, iy1 = win
        diff = np.zeros((iy1 - iy0 + 1, ix1 - ix0 + 2), dtype=np.int32)
        if not shape.empty and len(pts):
            _mark_inverse_trajectories(pts[:, 0], pts[:, 1], *shape.turned(angle),
                                       shape.strict, h, ix0, iy0, diff, xs_buf)
        return np.cumsum(diff, axis=1)[:, :-1] > 0

    def feasible(c_shapes: list[_TestShape], b_shapes: list[_TestShape],
                 win: tuple[int, int, int, int], angle: float) -> np.ndarray | None:
        """P at one angle on the lattice window: every orifice in C and none in B."""
        ix0, ix1, iy0, iy1 = win
        if ix1 < ix0 or iy1 < iy0:
            return None
        mask = np.ones((iy1 - iy0 + 1, ix1 - ix0 + 1), dtype=bool)
        for c_shape, b_shape in zip(c_shapes, b_shapes, strict=True):
            mask &= covered(c_shape, q_pts, win, angle)
            if not mask.any():
                break
            mask &= ~covered(b_shape, y_pts, win, angle)
        return mask

    regions: list[BaseGeometry] = []
    s_inner: list[BaseGeometry] = []
    s_outer: list[BaseGeometry] = []
    pieces_in = tuple(p for o in orifices for p in o.inner_pieces)
    pieces_out = tuple(p for o in orifices for p in o.outer_pieces)
    n_cells = 0
    for k, a in enumerate(angles):
        mask = feasible(c_in, b_in, windows[k], float(a))
        if mask is not None and mask.any():
            ix0, _, iy0, _ = windows[k]
            xs = (ix0 + np.arange(mask.shape[1])) * h
            ys = (iy0 + np.arange(mask.shape[0])) * h
            rects = grid_rectangles(mask, xs, ys, h)
            n_cells += int(mask.sum())
            regions.append(shapely.union_all(shapely.box(*rects.T)))
            s_inner.extend(cell_footprint_union(rects, pieces_in, float(a)))
        else:
            regions.append(MultiPolygon())
        if has_outer:
            mask = feasible(c_out, b_out, windows_out[k], float(a))
            if mask is not None and mask.any():
                ix0, _, iy0, _ = windows_out[k]
                xs = (ix0 + np.arange(mask.shape[1])) * h
                ys = (iy0 + np.arange(mask.shape[0])) * h
                rects = grid_rectangles(mask, xs, ys, h)
                s_outer.extend(cell_footprint_union(rects, pieces_out, float(a), grow=spin))

    as_built = shapely.union_all(s_inner) if s_inner else MultiPolygon()
    target_area = float(g.area)
    as_built_area = float(as_built.area)
    lost_hi = max(0.0, target_area - as_built_area)
    if has_outer:
        outer_geom = shapely.union_all(s_outer) if s_outer else MultiPolygon()
        lost_lo = max(0.0, target_area - float(shapely.intersection(outer_geom, g).area))
    else:
        lost_lo = 0.0
    lost_lo = min(lost_lo, lost_hi)

    # ---- components of P: pieces per angle, joined when they overlap at neighbouring angles
    pieces = [polygons_of(r) for r in regions]
    labels = component_labels(pieces, lambda _k, a, _k2, b: a.intersects(b), wrap=wrap)
    count = 1 + max((max(row) for row in labels if row), default=-1)
    members: list[list[BaseGeometry]] = [[] for _ in range(count)]
    for k, row in enumerate(labels):
        for i, c_id in enumerate(row):
            members[c_id].append(pieces[k][i])
    components = Components(
        count=count,
        geometries=tuple(shapely.union_all(m) for m in members),
        angle_ranges=tuple(angle_ranges(labels, angles)),
    )
    notes.insert(0, (
        f"reference: {len(y_pts):,} boundary samples ≤ {delta:g} mm apart, {len(q_pts):,} "
        f"interior samples every {q_spacing:.3g} mm, positions every {h:g} mm, "
        f"{len(angles)} angle(s); B tested with the nozzle grown by {eps:.3g} mm so P is "
        f"conservative; bounds from a pass with it shrunk by {rho_out:.3g} mm"
    ))
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
        motion=MotionRestriction(angles=angles, regions=tuple(regions)),
        components=components,
        resolution=h,
        angle_step=gap if turning else 0.0,
        elapsed=time.perf_counter() - t_start,
        notes=tuple(notes),
        extra={"boundary_samples": len(y_pts), "interior_samples": len(q_pts),
               "boundary_spacing": delta, "interior_spacing": q_spacing, "grow": eps,
               "shrink": rho_out, "feasible_cells": n_cells, "work_estimate": work},
    )

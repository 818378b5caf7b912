"""The setup of a reference-engine run: margins, samples, test shapes and the work budget.

For :mod:`printability.mmc.reference` (whose docstring states what the margins prove):
:func:`plan_run` fixes the lattice, the angles and the margins ε and ρ';
:func:`probe_shapes` the shapes the samples are tested against; :func:`budget` the
lattice windows and the work estimate, refused before anything heavy;
:func:`boundary_samples` and :func:`interior_samples` the points of ∂G and G; and
:class:`TurnedShape` and :class:`LatticeWindow` are the records the engine's kernel reads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from printability.errors import InputError, ResourceError
from printability.mmc.orifices import Orifice, angle_gap, offset_orifice, orifices_of
from printability.model.geometry import polygons_of, rotation_matrix
from printability.model.machine import Machine
from printability.model.nozzle import Nozzle
from printability.settings import Settings

__all__ = [
    "LatticeWindow",
    "Plan",
    "ProbeShape",
    "ProbeShapes",
    "TurnedShape",
    "Window",
    "boundary_samples",
    "budget",
    "interior_samples",
    "lattice_windows",
    "plan_run",
    "probe_shapes",
]

Window = tuple[int, int, int, int]
"""A lattice index window (ix0, ix1, iy0, iy1), bounds included."""


class TurnedShape(NamedTuple):
    """A test shape turned to one angle, as the kernel reads it (see :class:`ProbeShape`).

    ``kind`` 0: the disk of centre (dcx, dcy) and radius dr; 1: the polygon edges
    (ex0, ey0) → (ex1, ey1), even-odd rule. Its y extent is [ymin, ymax]; ``strict``
    counts only points strictly inside.
    """

    kind: int
    dcx: float
    dcy: float
    dr: float
    ex0: np.ndarray
    ey0: np.ndarray
    ex1: np.ndarray
    ey1: np.ndarray
    ymin: float
    ymax: float
    strict: bool


class LatticeWindow(NamedTuple):
    """The lattice of spacing ``h`` from index (ix0, iy0): column i, row j is t = (i·h, j·h)."""

    h: float
    ix0: int
    iy0: int


# --------------------------------------------------------------------------- samples


def boundary_samples(g: BaseGeometry, spacing: float) -> np.ndarray:
    """Points on every ring of ``g``, at most ``spacing`` apart along the ring."""
    out = []
    for poly in polygons_of(g):
        for ring in (poly.exterior, *poly.interiors):
            n = max(3, math.ceil(ring.length / spacing))
            d = np.arange(n) * (ring.length / n)
            out.append(shapely.get_coordinates(shapely.line_interpolate_point(ring, d)))
    return np.concatenate(out) if out else np.zeros((0, 2))


def interior_samples(g: BaseGeometry, spacing: float) -> np.ndarray:
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
class ProbeShape:
    """A shape in the nozzle frame that samples are tested against.

    Either a disk (``disk`` = (cx, cy, r), empty when r <= 0) or polygon edges
    ``edges`` (k, 4) = (x0, y0, x1, y1) of every ring (even-odd rule).
    """

    disk: tuple[float, float, float] | None
    edges: np.ndarray
    strict: bool

    def turned(self, angle: float) -> TurnedShape:
        """The kernel's record of the shape turned by ``angle`` degrees."""
        rot = rotation_matrix(angle)
        if self.disk is not None:
            cx, cy = rot @ np.asarray(self.disk[:2])
            r = self.disk[2]
            e = np.zeros(0)  # no edges (one array layout for the kernel: one compilation)
            return TurnedShape(0, float(cx), float(cy), float(r), e, e, e, e, float(cy - r),
                               float(cy + r), self.strict)
        a = self.edges[:, :2] @ rot.T
        b = self.edges[:, 2:] @ rot.T
        ys = np.concatenate([a[:, 1], b[:, 1]])
        return TurnedShape(1, 0.0, 0.0, 0.0, np.ascontiguousarray(a[:, 0]),
                           np.ascontiguousarray(a[:, 1]), np.ascontiguousarray(b[:, 0]),
                           np.ascontiguousarray(b[:, 1]), float(ys.min()), float(ys.max()),
                           self.strict)

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


def probe_shape(o: Orifice, base: str, offset: float, *, strict: bool) -> ProbeShape:
    """The orifice's inner or outer polygon offset by ``offset`` mm (> 0 out, < 0 in).

    See :func:`offset_orifice`; a circle is offset exactly.
    """
    if o.disk is not None:
        return ProbeShape((o.disk[0], o.disk[1], o.disk[2] + offset), np.zeros((0, 4)), strict)
    poly = offset_orifice(o, base, offset)
    edges = []
    for part in polygons_of(poly):
        for ring in (part.exterior, *part.interiors):
            c = np.asarray(ring.coords)
            edges.append(np.column_stack([c[:-1], c[1:]]))
    return ProbeShape(None, np.concatenate(edges) if edges else np.zeros((0, 4)), strict)


def lattice_windows(g: BaseGeometry, orifices: tuple[Orifice, ...], angles: np.ndarray,
                    h: float, pad: float) -> list[Window]:
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


@dataclass(frozen=True, eq=False)
class Plan:
    """The discretisation and the margins that make P conservative (module docstring).

    Attributes
    ----------
    h, delta
        Lattice spacing of the positions and largest gap between boundary samples, mm.
    angles, gap, wrap, turning
        The sampled angles (degrees), their largest gap, whether they wrap around, and
        whether turning the nozzle changes anything.
    orifices
        The nozzle's orifices.
    eps, spin, rho_out
        The B test's growth ε, the angular part r_max·Δφ/2 of ρ' and the optimistic
        pass's shrink ρ', mm.
    has_outer, q_spacing
        Whether the optimistic pass runs (ρ' below the inscribed radius) and the
        interior samples' spacing, mm.
    notes
        What the caller should be told.
    """

    h: float
    delta: float
    angles: np.ndarray
    gap: float
    wrap: bool
    turning: bool
    orifices: tuple[Orifice, ...]
    eps: float
    spin: float
    rho_out: float
    has_outer: bool
    q_spacing: float
    notes: tuple[str, ...]


def plan_run(nozzle: Nozzle, machine: Machine, settings: Settings,
             boundary_spacing: float | None) -> Plan:
    """The lattice, angles and margins of a run; InputError when it cannot run."""
    if not machine.separable:
        raise InputError(f"the reference engine needs a separable machine (xy or ttr); "
                         f"machine {machine.name!r} is a joint chain: use the sampled engine")
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
    return Plan(h, delta, angles, gap, wrap, turning, orifices, eps, spin, rho_out, has_outer,
                q_spacing, tuple(notes))


@dataclass(frozen=True, eq=False)
class ProbeShapes:
    """Per orifice, the test shapes of C (an interior sample inside it), B (a boundary
    sample within ε of it), and the optimistic pass's C' = B' (inside it shrunk by ρ')."""

    c_in: list[ProbeShape]
    b_in: list[ProbeShape]
    c_out: list[ProbeShape]
    b_out: list[ProbeShape]


def probe_shapes(plan: Plan) -> ProbeShapes:
    """The test shapes of both passes, per orifice."""
    orifices = plan.orifices
    return ProbeShapes(
        [probe_shape(o, "inner", 0.0, strict=True) for o in orifices],
        [probe_shape(o, "outer", plan.eps, strict=False) for o in orifices],
        [probe_shape(o, "inner", -plan.rho_out, strict=False) for o in orifices],
        [probe_shape(o, "inner", -plan.rho_out, strict=True) for o in orifices],
    )


def budget(g: BaseGeometry, plan: Plan, shapes: ProbeShapes, max_work: float,
           max_memory: float) -> tuple[list[Window], list[Window], float]:
    """The lattice windows of both passes and the work estimate, before anything heavy.

    Raises ResourceError above ``max_work`` operations or ``max_memory`` bytes.
    """
    h, delta, angles = plan.h, plan.delta, plan.angles
    windows = lattice_windows(g, plan.orifices, angles, h, pad=0.0)
    windows_out = lattice_windows(g, plan.orifices, angles, h, pad=plan.rho_out + h)
    n_t = sum(max(0, b - a + 1) * max(0, d - c + 1) for a, b, c, d in windows)
    n_t_out = sum(max(0, b - a + 1) * max(0, d - c + 1) for a, b, c, d in windows_out)
    n_boundary = sum(max(3, math.ceil(r.length / delta)) for p in polygons_of(g)
                     for r in (p.exterior, *p.interiors))
    n_interior = int(g.area / plan.q_spacing**2) + 1

    def shape_work(shapes: list[ProbeShape], n_samples: int) -> float:
        return sum(n_samples * (s.height / h + 1) * s.cost for s in shapes)

    def live(wins: list[Window]) -> int:
        return sum(1 for a, b, c, d in wins if b >= a and d >= c)

    work = live(windows) * (shape_work(shapes.c_in, n_interior)
                            + shape_work(shapes.b_in, n_boundary))
    if plan.has_outer:
        work += live(windows_out) * (shape_work(shapes.c_out, n_interior)
                                     + shape_work(shapes.b_out, n_boundary))
    work += 4 * len(plan.orifices) * (n_t + n_t_out)
    memory = 16 * (n_boundary + n_interior) + 24 * max(
        [max(0, b - a + 2) * max(0, d - c + 1) for a, b, c, d in windows_out] or [0])
    if work > max_work or memory > max_memory:
        raise ResourceError(
            f"the reference engine would need about {work:.2g} operations and "
            f"{memory / 2**20:.3g} MiB ({n_t + n_t_out:,} positions over {len(angles)} "
            f"angle(s), {n_boundary:,} boundary and {n_interior:,} interior samples), more "
            f"than its budget of {max_work:.2g} operations and {max_memory / 2**20:.3g}"
            f" MiB; it is meant for small checks: use a coarser resolution (now {h:g} mm), a "
            f"larger angle step, a smaller region, or the exact/raster engines"
        )
    return windows, windows_out, work

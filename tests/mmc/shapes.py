"""A shared catalogue of test shapes for every MMC engine's tests.

Import it from a test module in ``tests/mmc`` as ``from shapes import ...``
(pytest puts the test file's folder on ``sys.path``). Every shape is a
validated :class:`shapely.geometry.MultiPolygon` in mm.

Synthetic shapes have closed-form facts the tests use; real shapes come from
``../shared/data`` (see its SOURCES.md): slices of Thingiverse parts
(Kuipers et al. 2020, BSD-3) and Natural Earth coastlines (public domain).

Use :func:`catalogue` for parametrised tests::

    @pytest.mark.parametrize("shape", catalogue().values(), ids=str)
    def test_something(shape): ...
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import shapely
import shapely.affinity
from shapely.geometry import MultiPolygon, Point, Polygon, box

from printability.model.geometry import as_region

__all__ = [
    "SHARED_DATA",
    "Shape",
    "catalogue",
    "comb",
    "corner_arc_turn",
    "corner_catalogue",
    "corner_form_holds",
    "corner_loss",
    "ellipse_opening_loss",
    "l_shape",
    "load_coastline",
    "load_slice",
    "polygon",
    "random_convex",
    "rectangle",
    "regular_polygon",
    "ring",
    "slot",
    "star",
    "strip",
    "u_shape",
    "v_notch",
]

ROOT = Path(__file__).resolve().parents[2]
SHARED_DATA = Path(os.environ.get("PRINTABILITY_SHARED_DATA", ROOT.parent / "shared" / "data"))

#: Two small real slices used in the default catalogue (area ~50 and ~180 mm²).
REAL_SLICES = (
    "OpenRC-pinion-gear-motor--rotated_outline_mesh0_z5700.txt",
    "cableChain-plateMount-v2_outline_mesh0_z3900.txt",
)


@dataclass(frozen=True)
class Shape:
    """A named test region.

    Attributes
    ----------
    name
        Identifier (used as the pytest id).
    region
        The target G, mm.
    feature
        Width of the narrowest feature meant to print, mm: nozzles narrower
        than this print something there; tests size their nozzles from it.
    note
        What the shape exercises.
    """

    name: str
    region: MultiPolygon
    feature: float
    note: str = ""

    def __str__(self) -> str:
        return self.name


def _mp(geom) -> MultiPolygon:
    return as_region(geom)


# ----------------------------------------------------------------------- synthetic


def rectangle(w: float = 10.0, h: float = 4.0) -> MultiPolygon:
    """A w × h rectangle at the origin (corner at (0, 0)).

    A disk of radius r ≤ min(w, h)/2 opens it to a rounded rectangle: it
    loses exactly (4 − π)·r².
    """
    return _mp(box(0.0, 0.0, w, h))


def slot(width: float, length: float = 10.0, *, angle: float = 0.0) -> MultiPolygon:
    """A straight slot (channel) of ``width`` and ``length`` turned by ``angle`` degrees.

    Centred on the origin, long axis along x before turning.
    """
    g = box(-length / 2, -width / 2, length / 2, width / 2)
    if angle:
        g = shapely.affinity.rotate(g, angle, origin=(0.0, 0.0))
    return _mp(g)


def strip(width: float, length: float = 10.0) -> MultiPolygon:
    """A thin strip; any nozzle wider than ``width`` in every direction prints nothing."""
    return slot(width, length)


def u_shape(
    width: float = 10.0, height: float = 8.0, gap: float = 2.0, base: float = 2.0
) -> MultiPolygon:
    """The U-shape of the seed paper's Fig. 1: two arms joined by a base.

    Outer ``width`` × ``height``; a notch ``gap`` wide opens from the top down
    to ``base`` above the bottom, so each arm is (width − gap)/2 wide. The
    notch's two inner corners are reflex corners of G.
    """
    outer = box(0.0, 0.0, width, height)
    notch = box((width - gap) / 2, base, (width + gap) / 2, height + 1.0)
    return _mp(outer.difference(notch))


def l_shape(size: float = 10.0, arm: float = 3.0) -> MultiPolygon:
    """An L: two arms ``arm`` wide, ``size`` long, one reflex corner."""
    return _mp(box(0, 0, size, arm).union(box(0, 0, arm, size)))


def ring(outer: float = 5.0, inner: float = 3.0, *, quad_segs: int = 16) -> MultiPolygon:
    """An annulus (a ring with a hole) centred on the origin, radii in mm."""
    return _mp(Point(0, 0).buffer(outer, quad_segs=quad_segs)
               .difference(Point(0, 0).buffer(inner, quad_segs=quad_segs)))


def comb(
    widths: tuple[float, ...] = (0.3, 0.5, 0.8, 1.2, 2.0),
    *,
    tooth: float = 5.0,
    spine: float = 2.0,
    spacing: float = 1.0,
) -> MultiPolygon:
    """A comb: a spine with teeth of graded widths (a nozzle loses every tooth narrower than it)."""
    parts = []
    x = 0.0
    for w in widths:
        parts.append(box(x, spine, x + w, spine + tooth))
        x += w + spacing
    parts.append(box(0.0, 0.0, x - spacing, spine + 1e-9))
    return _mp(shapely.union_all(parts))


def star(points: int = 5, r_out: float = 5.0, r_in: float = 2.0) -> MultiPolygon:
    """A star polygon: sharp convex tips (always lost) and reflex notches."""
    t = np.arange(2 * points) * math.pi / points + math.pi / 2
    r = np.where(np.arange(2 * points) % 2 == 0, r_out, r_in)
    return _mp(Polygon(np.column_stack([r * np.cos(t), r * np.sin(t)])))


def polygon(*vertices: tuple[float, float], holes=()) -> MultiPolygon:
    """A polygon given by its vertices, kept in the order given (CW or CCW)."""
    return _mp(Polygon(vertices, holes))


def regular_polygon(n: int = 6, radius: float = 6.0, *, cw: bool = False) -> MultiPolygon:
    """A regular n-gon centred on the origin, circumradius ``radius``; CCW unless ``cw``."""
    t = 2 * math.pi * np.arange(n) / n
    pts = np.column_stack([radius * np.cos(t), radius * np.sin(t)])
    return _mp(Polygon(pts[::-1] if cw else pts))


def v_notch(
    width: float = 12.0, height: float = 10.0, mouth: float = 4.0, depth: float = 6.0
) -> MultiPolygon:
    """A ``width`` × ``height`` block with a V cut ``mouth`` wide, ``depth`` deep from the top.

    The tip of the V is a reflex corner (loses nothing to a disk), the two
    corners at its mouth are convex.
    """
    c = width / 2
    return _mp(Polygon([(0, 0), (width, 0), (width, height), (c + mouth / 2, height),
                        (c, height - depth), (c - mouth / 2, height), (0, height)]))


def random_convex(seed: int, n: int = 7, radius: float = 8.0) -> MultiPolygon:
    """A convex polygon with ``n`` vertices on a circle at seeded random angles.

    Successive vertices are at least 25° apart, so no corner is sharper than
    the inscribed angle 25°/2 and every edge is ≥ 2·radius·sin(12.5°) long.
    """
    rng = np.random.default_rng(seed)
    gap = math.radians(25.0)
    free = 2 * math.pi - n * gap
    t = np.sort(rng.uniform(0.0, free, n)) + gap * np.arange(n) + rng.uniform(0, 2 * math.pi)
    pts = np.column_stack([radius * np.cos(t), radius * np.sin(t)])
    return _mp(Polygon(pts[::-1] if seed % 2 else pts))  # odd seeds clockwise


def _oriented_rings(region: MultiPolygon):
    """Every ring's vertices (k, 2), not closed, with the region's interior on the left."""
    for q in region.geoms:
        q = shapely.geometry.polygon.orient(q, 1.0)
        for ring_ in (q.exterior, *q.interiors):
            yield np.asarray(ring_.coords)[:-1]


def _turns(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed turn τ at each vertex (> 0: convex, interior angle π − τ) and edge lengths."""
    u = v - np.roll(v, 1, axis=0)  # edge into each vertex
    w = np.roll(u, -1, axis=0)  # edge out of it
    tau = np.arctan2(u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0], np.einsum("ij,ij->i", u, w))
    return tau, np.hypot(*w.T)


def corner_loss(region: MultiPolygon, r: float) -> float:
    """Closed-form area a disk of radius r loses when it opens a polygon (mm²).

    Each convex corner of interior angle θ loses r²·(cot(θ/2) − (π − θ)/2) =
    r²·(tan(τ/2) − τ/2) with τ = π − θ its turn (the area between the corner
    and the disk touching both edges); reflex corners lose nothing. Holds
    while :func:`corner_form_holds`.
    """
    total = 0.0
    for v in _oriented_rings(region):
        tau, _ = _turns(v)
        tau = tau[tau > 0]
        total += float(np.sum(np.tan(tau / 2) - tau / 2))
    return r * r * total


def corner_arc_turn(region: MultiPolygon) -> float:
    """Σ τ over convex corners: the as-built boundary has arcs of total length r·Σ τ."""
    return float(sum(np.sum(np.clip(_turns(v)[0], 0.0, None)) for v in _oriented_rings(region)))


def corner_form_holds(region: MultiPolygon, r: float) -> bool:
    """Whether :func:`corner_loss` is the exact opening loss of ``region`` by a disk of radius r.

    Necessary and sufficient for the shapes built here: at each convex corner
    the disk touches both edges at r·tan(τ/2) from the corner, and along every
    edge the tangent points of its two ends must not cross. Checked also
    against the erosion being non-empty in every polygon (no part too narrow).
    """
    for v in _oriented_rings(region):
        tau, length = _turns(v)
        t = np.where(tau > 0, r * np.tan(np.clip(tau, 0.0, None) / 2), 0.0)
        if np.any(t + np.roll(t, -1) > length * (1 - 1e-9)):
            return False
    return all(not shapely.buffer(q, -r).is_empty for q in region.geoms)


def ellipse_opening_loss(region: MultiPolygon, a: float, b: float, angles, *,
                         quad_segs: int = 64) -> tuple[float, float]:
    """An independent oracle: λ(G \\ ∪_φ opening(G, R(φ)·diag(a, b)·D)) over ``angles``.

    The affine trick with plain shapely buffers (no code of the engines): for each
    angle the region is mapped by L⁻¹, opened by the unit disk (``buffer(-1)`` then
    ``buffer(1)``), mapped back; the union over angles is clipped to G.

    Returns
    -------
    (lost, tolerance)
        The lost area, mm², and an allowance for the buffers' chords: GEOS fillet
        chords span at most 1.5 quanta, so each offset is within 1 − cos(3π/(8·quad_segs))
        of the true one in the unit-disk frame, at most a·(that) in the world, and the
        area is off by at most that times the boundaries' length, twice (erosion and
        dilation), for G and for S. (GEOS also drops "shallow concavities" closer than
        0.01 of the offset to their neighbours' chord, which finely drawn curves have:
        use the tolerance on polygons drawn with few vertices.)
    """
    pieces = []
    for phi in angles:
        c, s = math.cos(math.radians(phi)), math.sin(math.radians(phi))
        lm = np.array([[c, -s], [s, c]]) @ np.diag([a, b])
        li = np.linalg.inv(lm)
        mapped = shapely.affinity.affine_transform(region, [*li.ravel(), 0, 0])
        opened = mapped.buffer(-1.0, quad_segs=quad_segs).buffer(1.0, quad_segs=quad_segs)
        pieces.append(shapely.affinity.affine_transform(opened, [*lm.ravel(), 0, 0]))
    built = shapely.union_all(pieces).intersection(region)
    chord = max(a, b) * (1.0 - math.cos(3 * math.pi / (8 * quad_segs)))
    return float(region.area - built.area), 2.0 * chord * float(region.length + built.length)


# ----------------------------------------------------------------------------- real


def load_slice(path: str | Path) -> tuple[MultiPolygon, float, float]:
    """Read a slice of ``shared/data/slices``.

    Format: line 1 and 2 the minimal and maximal bead width (mm); then curves,
    each a count line followed by that many "x y" lines (mm). Outer
    boundaries and holes are not marked: nest by even-odd (symmetric
    difference of the curves).

    Returns
    -------
    (region, min_width, max_width)
        The region is translated so its bounding box starts at (0, 0).
    """
    lines = [s.strip() for s in Path(path).read_text().splitlines()]
    lines = [s for s in lines if s]
    lo, hi = float(lines[0]), float(lines[1])
    i, g = 2, None
    while i < len(lines):
        n = int(lines[i])
        pts = np.array([[float(v) for v in s.split()] for s in lines[i + 1 : i + 1 + n]])
        i += n + 1
        poly = shapely.make_valid(Polygon(pts))
        g = poly if g is None else g.symmetric_difference(poly)
    region = _mp(g)
    minx, miny, _, _ = region.bounds
    return _mp(shapely.affinity.translate(region, -minx, -miny)), lo, hi


def load_coastline(name: str = "japan_10m", *, size: float = 100.0, keep: int = 4) -> MultiPolygon:
    """A Natural Earth country, projected and scaled to ``size`` mm.

    The ``keep`` largest polygons are kept (Japan: Honshu, Hokkaido, Kyushu,
    Shikoku). Projection: local equirectangular, x = lon·111.32·cos(lat₀),
    y = lat·110.57 (km), lat₀ the middle latitude; then translated to the
    origin and scaled so the larger bounding-box side is ``size``.
    """
    doc = json.loads((SHARED_DATA / f"{name}.geojson").read_text())
    geom = shapely.geometry.shape(doc["geometry"])
    polys = sorted(shapely.get_parts(geom), key=lambda p: -p.area)[:keep]
    g = MultiPolygon(polys)
    lat0 = math.radians((g.bounds[1] + g.bounds[3]) / 2)
    g = shapely.transform(g, lambda c: c * [111.32 * math.cos(lat0), 110.57])
    minx, miny, maxx, maxy = g.bounds
    scale = size / max(maxx - minx, maxy - miny)
    return _mp(shapely.transform(g, lambda c: (c - [minx, miny]) * scale))


# ------------------------------------------------------------------------ catalogue


@lru_cache(maxsize=1)
def catalogue(*, real: bool = True) -> dict[str, Shape]:
    """Every shape by name; the real ones only when ``../shared/data`` is present."""
    shapes = [
        Shape("rectangle", rectangle(10.0, 4.0), 4.0, "loses (4 − π)r² to a disk"),
        Shape("strip", strip(0.5, 10.0), 0.5, "vanishes under any nozzle wider than 0.5"),
        Shape("slot_30deg", slot(1.0, 8.0, angle=30.0), 1.0, "a turned channel"),
        Shape("u_shape", u_shape(), 2.0, "the seed paper's Fig. 1"),
        Shape("l_shape", l_shape(), 3.0, "one reflex corner"),
        Shape("ring", ring(), 2.0, "a hole; curved boundary"),
        Shape("comb", comb(), 0.3, "teeth of graded widths"),
        Shape("star", star(), 1.0, "sharp tips and reflex notches"),
    ]
    if real and (SHARED_DATA / "slices").is_dir():
        for fname in REAL_SLICES:
            region, lo, _ = load_slice(SHARED_DATA / "slices" / fname)
            shapes.append(Shape("slice:" + fname.split("_outline")[0], region, lo,
                                "a real print layer (Kuipers et al. 2020)"))
    return {s.name: s for s in shapes}


@lru_cache(maxsize=1)
def corner_catalogue() -> dict[str, Shape]:
    """Polygons whose opening by a disk has the corner closed form :func:`corner_loss`.

    Triangles (acute, right, obtuse) in both orientations, convex and
    non-convex polygons (an hourglass, a V-notch), a block with a triangular
    hole, a regular hexagon and seeded random convex polygons. Every feature
    is ≥ 4 mm wide: :func:`corner_form_holds` for disks up to ``feature`` = 2 mm
    across, the largest diameter the tests use. No
    self-intersecting input: a bow-tie is split into two triangles by
    :func:`printability.model.geometry.as_region` and is tested on its own.
    """
    tri = {"acute": ((0, 0), (12, 0), (5, 10)),
           "right": ((0, 0), (12, 0), (0, 9)),
           "obtuse": ((0, 0), (20, 0), (-4, 7)),
           "issue26": ((0, 0), (20, 0), (10, 10))}
    shapes = []
    for kind, v in tri.items():
        shapes.append(Shape(f"triangle_{kind}_ccw", polygon(*v), 2.0, "three convex corners"))
        shapes.append(Shape(f"triangle_{kind}_cw", polygon(*v[::-1]), 2.0,
                            "the same, clockwise"))
    shapes += [
        Shape("hexagon", regular_polygon(6, 6.0), 2.0, "six 120° corners (tiny loss)"),
        Shape("hexagon_cw", regular_polygon(6, 6.0, cw=True), 2.0, "the same, clockwise"),
        Shape("pentagon", polygon((0, 0), (14, 1), (16, 9), (7, 14), (-2, 8)), 2.0,
              "an irregular convex pentagon"),
        Shape("hourglass", polygon((0, 0), (12, 0), (8, 6), (12, 12), (0, 12), (4, 6)), 2.0,
              "a bow-tie-like non-convex polygon: two reflex corners at a 4 mm waist"),
        Shape("v_notch", v_notch(), 2.0, "a V cut: a reflex tip, two convex mouth corners"),
        Shape("arrow", polygon((0, 4), (10, 4), (10, 0), (18, 7), (10, 14), (10, 10),
                               (0, 10)), 2.0, "a non-convex arrow"),
        Shape("triangle_hole", polygon((0, 0), (20, 0), (20, 18), (0, 18),
                                       holes=[((6, 5), (14, 5), (10, 12))]), 2.0,
              "a three-vertex hole: its corners are reflex corners of G"),
    ]
    shapes += [Shape(f"random_convex_{seed}", random_convex(seed, n), 2.0,
                     "seeded random convex polygon")
               for seed, n in ((1, 5), (2, 6), (3, 7), (4, 8))]
    return {s.name: s for s in shapes}

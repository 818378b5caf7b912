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

from printability.geometry import as_region

__all__ = [
    "SHARED_DATA",
    "Shape",
    "catalogue",
    "comb",
    "l_shape",
    "load_coastline",
    "load_slice",
    "rectangle",
    "ring",
    "slot",
    "star",
    "strip",
    "u_shape",
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

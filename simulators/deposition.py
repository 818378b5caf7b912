"""What the virtual printer deposits: swept nozzle footprints per layer, and the record.

Every extruding block sweeps the nozzle footprint R(φ)·A⁰ + t along its
segment. A convex orifice translating at a fixed angle sweeps exactly the
convex hull of its two end placements; a non-convex one sweeps the union of
its two placements and of the parallelograms its edges trace. When the angle
changes during the block, the block is cut into pieces short enough that no
nozzle point moves sideways by more than ``chord_tolerance`` (nozzle radius ×
Δφ per piece), and each piece is swept at interpolated poses. Layers are keyed
by the nozzle Z (rounded to ``z_resolution``).

Hulls are built in bulk (shapely's vectorised ``multipoints`` + ``convex_hull``)
and unioned per layer when the record is made, so streaming stays fast.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon
from shapely.strtree import STRtree

from printability.base.errors import PrintabilityOSError
from printability.base.files import replace_file
from printability.model.geometry import polygons_of
from printability.model.layers import LayerStack
from printability.model.nozzle import Nozzle

__all__ = ["Deposition", "DepositionRecord", "LayerRecord", "Violation", "write_record"]


@dataclass(frozen=True)
class Violation:
    """Material deposited outside the target (an MMC violation).

    Attributes
    ----------
    z
        Layer height, mm.
    bbox
        (xmin, ymin, xmax, ymax) of the offending material, mm.
    area
        mm².
    first_line
        Host line number (``N``) of the first command whose sweep made it,
        or None when the host sent no line numbers.
    first_index
        Index of that command in the executed log.
    first_text
        Its text.
    """

    z: float
    bbox: tuple[float, float, float, float]
    area: float
    first_line: int | None
    first_index: int
    first_text: str


@dataclass(frozen=True)
class LayerRecord:
    """One deposited layer: region, statistics and (with a target) the comparison."""

    z: float
    region: MultiPolygon
    moves: int
    path_length: float
    extruded: float
    target_area: float | None = None
    coverage: float | None = None
    outside_area: float | None = None

    @property
    def area(self) -> float:
        return float(self.region.area)


@dataclass(frozen=True)
class DepositionRecord:
    """The record of one run: layers, the executed log, statistics and MMC findings."""

    layers: tuple[LayerRecord, ...]
    log: tuple[tuple[int | None, str], ...]
    stats: dict[str, Any] = field(default_factory=dict)
    violations: tuple[Violation, ...] = ()
    target: str | None = None

    def to_json(self, *, precision: int = 5) -> dict[str, Any]:
        """A JSON-ready dict; regions as WKT (mm)."""
        return {
            "format": "printability-simulator-record",
            "version": 1,
            "units": "mm",
            "stats": self.stats,
            "target": self.target,
            "layers": [{
                "z": lr.z, "moves": lr.moves, "path_length": lr.path_length,
                "extruded": lr.extruded, "deposited_area": lr.area,
                "target_area": lr.target_area, "coverage": lr.coverage,
                "outside_area": lr.outside_area,
                "region_wkt": shapely.to_wkt(lr.region, rounding_precision=precision),
            } for lr in self.layers],
            "violations": [{
                "z": v.z, "bbox": list(v.bbox), "area": v.area, "first_line": v.first_line,
                "first_index": v.first_index, "first_text": v.first_text,
            } for v in self.violations],
            "log": [[n, t] for n, t in self.log],
        }


def write_record(record: DepositionRecord, path: str | os.PathLike[str]) -> Path:
    """Write the record as JSON atomically (temporary file + ``os.replace``)."""
    path = Path(path)
    data = json.dumps(record.to_json(), indent=1, allow_nan=False)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # a record is an ordinary file: 0666 less the umask, or the mode of the one it replaces
        replace_file(path, data.encode("utf-8"))
    except OSError as exc:
        raise PrintabilityOSError(f"{path}: cannot write the simulator record "
                                  f"({exc.strerror or exc})") from None
    return path


class _Layer:
    __slots__ = ("extruded", "geoms", "hull_idx", "hull_pts", "length", "line_of_geom",
                 "line_of_hull", "moves", "z")

    def __init__(self, z: float) -> None:
        self.z = z
        self.hull_pts: list[np.ndarray] = []   # point sets whose convex hull is swept
        self.line_of_hull: list[int] = []
        self.geoms: list[Polygon] = []         # non-convex sweeps, built directly
        self.line_of_geom: list[int] = []
        self.moves = 0
        self.length = 0.0
        self.extruded = 0.0


class Deposition:
    """Accumulates swept footprints per layer.

    Parameters
    ----------
    nozzle
        The nozzle; ``outline(angle)`` is its footprint at the origin.
    quad_segs
        Segments per quarter circle of round outlines.
    chord_tolerance
        Largest sideways error when subdividing a turning block, mm.
    z_resolution
        Layers closer than this in Z are one layer, mm.
    """

    def __init__(self, nozzle: Nozzle, *, quad_segs: int = 8, chord_tolerance: float = 0.005,
                 z_resolution: float = 1e-3) -> None:
        self.nozzle = nozzle
        self.chord_tolerance = chord_tolerance
        self.z_resolution = z_resolution
        base = nozzle.outline(0.0, quad_segs=quad_segs)
        self._parts = [np.asarray(p.exterior.coords[:-1], dtype=float) for p in polygons_of(base)]
        self._convex = [Polygon(p).convex_hull.area - Polygon(p).area <= 1e-12 * max(
            Polygon(p).area, 1.0) for p in self._parts]
        self._radius = max(float(np.max(np.hypot(p[:, 0], p[:, 1]))) for p in self._parts)
        self._rotates = not nozzle.is_round
        self.layers: dict[float, _Layer] = {}

    def _layer(self, z: float) -> _Layer:
        key = round(round(z / self.z_resolution) * self.z_resolution, 9)
        lay = self.layers.get(key)
        if lay is None:
            lay = self.layers[key] = _Layer(key)
        return lay

    def add(self, start: np.ndarray, end: np.ndarray, extruded: float, index: int) -> None:
        """Sweep the footprint from ``start`` to ``end`` ((x, y, z, c) native) for log entry
        ``index``. Z of the layer is the end point's."""
        lay = self._layer(float(end[2]))
        lay.moves += 1
        lay.length += float(math.hypot(end[0] - start[0], end[1] - start[1]))
        lay.extruded += extruded
        c0, c1 = float(start[3]), float(end[3])
        n = 1
        if self._rotates and c0 != c1:
            n = max(1, math.ceil(self._radius * math.radians(abs(c1 - c0)) /
                                 self.chord_tolerance))
        for k in range(n):
            t0, t1 = k / n, (k + 1) / n
            p0 = start[:2] + (end[:2] - start[:2]) * t0
            p1 = start[:2] + (end[:2] - start[:2]) * t1
            a0 = c0 + (c1 - c0) * t0
            a1 = c0 + (c1 - c0) * t1
            self._sweep(lay, p0, p1, a0, a1, index)

    def _sweep(self, lay: _Layer, p0: np.ndarray, p1: np.ndarray, a0: float, a1: float,
               index: int) -> None:
        r0 = _rot(a0)
        r1 = r0 if a1 == a0 else _rot(a1)
        for part, convex in zip(self._parts, self._convex, strict=True):
            q0 = part @ r0.T + p0
            q1 = part @ r1.T + p1
            if convex:
                lay.hull_pts.append(np.vstack([q0, q1]))
                lay.line_of_hull.append(index)
            else:
                # Exact Minkowski sum of a segment and a non-convex polygon.
                d = p1 - p0
                quads = [Polygon([q0[i], q0[(i + 1) % len(q0)], q0[(i + 1) % len(q0)] + d,
                                  q0[i] + d]) for i in range(len(q0))]
                g = shapely.union_all([Polygon(q0), Polygon(q1), *[q for q in quads
                                                                   if q.area > 0]])
                lay.geoms.append(g)
                lay.line_of_geom.append(index)

    def pieces(self, lay: _Layer) -> tuple[np.ndarray, np.ndarray]:
        """All swept pieces of a layer and the log index of each."""
        geoms: list[Any] = []
        idx: list[int] = []
        if lay.hull_pts:
            counts = np.array([len(p) for p in lay.hull_pts])
            pts = np.vstack(lay.hull_pts)
            which = np.repeat(np.arange(len(counts)), counts)
            hulls = shapely.convex_hull(shapely.multipoints(pts, indices=which))
            geoms.extend(hulls)
            idx.extend(lay.line_of_hull)
        geoms.extend(lay.geoms)
        idx.extend(lay.line_of_geom)
        return np.asarray(geoms, dtype=object), np.asarray(idx, dtype=int)

    def region(self, z: float) -> MultiPolygon:
        """Deposited region of the layer at ``z`` (empty when nothing was deposited)."""
        lay = self.layers.get(round(round(z / self.z_resolution) * self.z_resolution, 9))
        if lay is None:
            return MultiPolygon()
        return _as_multi(shapely.union_all(self.pieces(lay)[0]))

    def record(self, log: list[tuple[int | None, str]], *, stats: dict[str, Any] | None = None,
               target: LayerStack | None = None, tolerance: float = 1e-3,
               min_area: float = 1e-6) -> DepositionRecord:
        """Build the record; with a target, report coverage and MMC violations.

        Parameters
        ----------
        log
            Executed commands (line number, text) in order.
        target
            The layers that should have been printed. A planar target (one
            layer of height 0) applies to every deposited layer; otherwise a
            deposited layer is compared with the target layer of the same Z
            (within half the smallest layer height), and material on a Z with
            no target layer is all outside.
        tolerance
            Material within this distance of the target counts as inside, mm.
        min_area
            Smaller outside pieces are ignored, mm².
        """
        layers, violations = [], []
        tz = [lay.z for lay in target] if target is not None else []
        heights = [lay.height for lay in target if lay.height > 0] if target is not None else []
        ztol = max(0.5 * min(heights), 1e-6) if heights else 1e-6
        for z in sorted(self.layers):
            lay = self.layers[z]
            geoms, idx = self.pieces(lay)
            region = _as_multi(shapely.union_all(geoms))
            t_area = cov = out_area = None
            if target is not None:
                g = None
                if target.is_planar:
                    g = target[0].region
                elif tz:
                    k = int(np.argmin(np.abs(np.asarray(tz) - z)))
                    if abs(tz[k] - z) <= ztol:
                        g = target[k].region
                if g is None:
                    outside = region
                    t_area, cov = 0.0, None
                else:
                    t_area = float(g.area)
                    inside = region.intersection(g)
                    cov = float(inside.area / t_area) if t_area > 0 else None
                    outside = region.difference(g.buffer(tolerance, quad_segs=8))
                out_polys = [p for p in polygons_of(outside) if p.area > min_area]
                out_area = float(sum(p.area for p in out_polys))
                if out_polys:
                    tree = STRtree(geoms)
                    for p in sorted(out_polys, key=lambda q: q.bounds):
                        hits = [int(h) for h in tree.query(p, predicate="intersects")
                                if geoms[int(h)].intersection(p).area > min_area * 1e-3]
                        first = int(min(idx[hits])) if hits else -1
                        n, text = log[first] if 0 <= first < len(log) else (None, "")
                        violations.append(Violation(z, tuple(float(b) for b in p.bounds),
                                                    float(p.area), n, first, text))
            layers.append(LayerRecord(z, region, lay.moves, lay.length, lay.extruded,
                                      t_area, cov, out_area))
        return DepositionRecord(tuple(layers), tuple(log), dict(stats or {}), tuple(violations),
                                target.source if target is not None else None)


def _rot(angle_deg: float) -> np.ndarray:
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s], [s, c]])


def _as_multi(geom: Any) -> MultiPolygon:
    polys = polygons_of(geom)
    return MultiPolygon(polys) if polys else MultiPolygon()

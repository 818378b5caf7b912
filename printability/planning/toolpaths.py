"""Toolpaths inside a layer for ``printability generate``: perimeters, infill, ordering.

Plain geometry on shapely regions; the orientation of every move and what
is MMC-safe are decided afterwards by :func:`printability.planning.orientation.
plan_orientations`, which cuts away whatever the nozzle cannot lay inside G.

* **Perimeters** follow the boundary of G at the nozzle's narrowest bead
  ``w_p`` (an ellipse moving along its major axis): the k-th loop is the
  boundary of G eroded by ``w_p·(k + ½)``, so the outermost bead's edge lies on
  ∂G. Narrow channels keep a loop as long as the erosion leaves something.
* **Infill** fills what the perimeters leave with parallel lines spaced by
  the widest bead ``w_f`` the nozzle lays (turned across the motion), the
  scan direction alternating by 90° between layers.
* **Ordering**: the groups (one per loop or per infill island) are visited
  in the order of a greedy travelling-salesman tour (networkx) over their
  entry points, each loop entered at its vertex nearest the previous exit,
  infill lines in boustrophedon order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import networkx as nx
import numpy as np
import shapely
from shapely.geometry import LineString
from shapely.geometry.base import BaseGeometry

from printability.model.geometry import polygons_of

__all__ = ["PathGroup", "infill_lines", "order_groups", "perimeter_loops"]


@dataclass(frozen=True)
class PathGroup:
    """Polylines printed one after the other without leaving the group.

    Attributes
    ----------
    kind
        ``"outer_wall"``, ``"inner_wall"`` or ``"sparse_infill"`` (a category of
        :data:`gcode.CATEGORIES`).
    paths
        Each path a (k, 2) array of points, mm; a loop repeats its first point.
    width
        Planned bead width, mm.
    closed
        True for loops (their start may be rotated freely).
    """

    kind: str
    paths: tuple[np.ndarray, ...]
    width: float
    closed: bool

    @property
    def start(self) -> np.ndarray:
        return self.paths[0][0]

    @property
    def end(self) -> np.ndarray:
        return self.paths[-1][-1]


def _rings(geom: BaseGeometry) -> list[np.ndarray]:
    out = []
    for poly in polygons_of(geom):
        for ring in (poly.exterior, *poly.interiors):
            xy = np.asarray(ring.coords)
            if len(xy) >= 4:
                out.append(xy)
    return out


def perimeter_loops(region: BaseGeometry, width: float, count: int) -> tuple[list[PathGroup],
                                                                              BaseGeometry]:
    """``count`` loops at spacing ``width`` inside ``region``; and what is left inside them.

    Returns
    -------
    (groups, interior)
        One group per loop (outermost first) and the region the infill must
        fill (G eroded by ``count·width``).
    """
    groups: list[PathGroup] = []
    for k in range(count):
        inner = region.buffer(-width * (k + 0.5), quad_segs=8, join_style="round")
        if inner.is_empty:
            break
        kind = "outer_wall" if k == 0 else "inner_wall"
        for ring in _rings(inner):
            groups.append(PathGroup(kind, (ring,), width, True))
    interior = region.buffer(-width * count, quad_segs=8) if count else region
    return groups, interior


def infill_lines(region: BaseGeometry, spacing: float, angle: float) -> list[PathGroup]:
    """Parallel lines ``spacing`` apart at ``angle`` degrees, clipped to ``region``.

    One group per island of the region, lines in boustrophedon order.
    """
    groups: list[PathGroup] = []
    if region.is_empty or spacing <= 0:
        return groups
    a = math.radians(angle)
    d = np.array([math.cos(a), math.sin(a)])
    nrm = np.array([-d[1], d[0]])
    for island in polygons_of(region):
        xy = np.asarray(island.exterior.coords)
        proj_n = xy @ nrm
        proj_d = xy @ d
        lo, hi = proj_n.min() + spacing / 2, proj_n.max()
        if hi < lo:
            continue
        offs = np.arange(lo, hi, spacing)
        if offs.size == 0:
            continue
        t0, t1 = proj_d.min() - 1.0, proj_d.max() + 1.0
        lines = [np.array([o * nrm + t0 * d, o * nrm + t1 * d]) for o in offs]
        clipped = shapely.intersection(shapely.linestrings(lines), island)
        paths = []
        flip = False
        for geom in clipped:
            parts = [p for p in shapely.get_parts(geom) if isinstance(p, LineString)
                     and p.length > 1e-9]
            parts.sort(key=lambda p: np.asarray(p.coords)[0] @ d)
            if flip:
                parts = [LineString(np.asarray(p.coords)[::-1]) for p in reversed(parts)]
            for p in parts:
                paths.append(np.asarray(p.coords))
            if parts:
                flip = not flip
        if paths:
            groups.append(PathGroup("sparse_infill", tuple(paths), spacing, False))
    return groups


def _rotate_loop(ring: np.ndarray, near: np.ndarray) -> np.ndarray:
    """The loop started at its vertex nearest ``near``."""
    pts = ring[:-1]
    j = int(np.argmin(np.hypot(*(pts - near).T)))
    return np.vstack([pts[j:], pts[:j], pts[j:j + 1]])


def order_groups(groups: list[PathGroup], start: np.ndarray) -> list[PathGroup]:
    """Visit the groups along a greedy TSP tour from ``start`` (networkx); walls before infill.

    Outer walls of an island are printed before its inner walls only as the
    tour allows; every loop is entered at its vertex nearest the previous exit.
    """
    out: list[PathGroup] = []
    pos = np.asarray(start, dtype=float)
    for kinds in (("outer_wall", "inner_wall"), ("sparse_infill",)):
        todo = [g for g in groups if g.kind in kinds]
        if not todo:
            continue
        if len(todo) > 2:
            pts = np.array([pos] + [g.paths[0][0] for g in todo])
            graph = nx.Graph()
            n = len(pts)
            dist = np.hypot(pts[:, None, 0] - pts[None, :, 0], pts[:, None, 1] - pts[None, :, 1])
            for i in range(n):
                for j in range(i + 1, n):
                    graph.add_edge(i, j, weight=float(dist[i, j]))
            tour = nx.approximation.greedy_tsp(graph, weight="weight", source=0)
            seq = [todo[i - 1] for i in tour[1:-1]]
        else:
            seq = todo
        for g in seq:
            if g.closed:
                g = PathGroup(g.kind, (_rotate_loop(g.paths[0], pos),), g.width, True)
            elif np.hypot(*(g.end - pos)) < np.hypot(*(g.start - pos)):
                g = PathGroup(g.kind, tuple(p[::-1] for p in reversed(g.paths)), g.width, False)
            out.append(g)
            pos = g.end
    return out

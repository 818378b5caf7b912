"""The layer targets the post-processor plans against, built from the slicer's own beads.

G is the union of a layer's part beads as :mod:`printability.sources.gcode`
rebuilds it (the same reconstruction as ``printability analyze``). The planner
tests footprints against G grown by the tolerance: the bead union of
:mod:`printability.planning.beadunion` (no GEOS overlay), for batches of layers
laid side by side (:mod:`printability.planning.tiles`), or, for a tolerance too
small for that construction, GEOS's union and buffer, one layer at a time.
Targets are built on threads while the planner works.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from printability.base.arrays import take_rows
from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.planning.beadunion import INNER, SIDE, bead_union
from printability.planning.footprints import grown_target
from printability.planning.tiles import tile_index, tile_layers
from printability.settings import Settings
from printability.sources.gcode import layer_beads, layer_regions

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["layer_targets", "threaded"]

_BATCH_AREA = 250_000.0
"""Largest area (mm²) the tiles of one batch of layers cover: up to it, the boundary grid of
:func:`printability.planning.fastfit.boundary_grid` keeps its 1 mm cells."""
_BATCH_BEADS = 20_000
"""Most beads in one batch (about 45 MB of bead polygons)."""
_TILE_GAP = 1.0
"""Space between the tiles of a batch, mm."""


def layer_targets(g, filament_diameter: float, quad_segs: int, tolerance: float, *,
                  workers: int = 1, planned: tuple, reach: float, interior: bool = False
                  ) -> Iterator[tuple[list[int], np.ndarray, object, list[float], bool]]:
    """The layers that have a target, in batches, in order: per batch (its layers, their
    translations (n, 2) mm, the prepared target the planner tests footprints against,
    the area of G of each layer in mm², whether it is the last batch: no target is being
    built any more).

    G is the union of the layer's beads as :mod:`printability.sources.gcode` rebuilds it
    (the same reconstruction as ``printability analyze``, so the two agree on what the
    part is). The planner tests against G grown by ``tolerance``: the bead union of
    :mod:`printability.planning.beadunion`, built without an overlay, for which the area of
    G is the union's less :data:`~printability.planning.beadunion.SIDE` × ``tolerance`` × its
    perimeter (within that much of the exact area). Layers are laid side by side
    (:mod:`printability.planning.tiles`) so that one union serves a batch; each tile holds
    the layer's beads and its ``planned`` moves
    (``(seg, order, bounds)``: chords, their order by layer and each layer's rows of
    it, ``bounds`` one entry per layer of ``g`` and one more) grown by ``reach``, the
    nozzle's radius. A layer that repeats an earlier one of its batch to the bit (its
    beads and planned chords) is given that layer's translation and adds nothing to the
    union (:func:`_layer_kinds`). A tolerance too small for the bead union falls back to
    GEOS (the union, then a buffer), one layer per batch. ``interior``: G with the gaps the
    slicer leaves inside the object filled back (:func:`~printability.sources.gcode.
    fill_interior`), built by GEOS one layer per batch. Targets are built on
    ``workers`` threads while the caller plans; the first, which the caller waits for,
    is itself shared out over them.
    """
    settings = Settings(quad_segs=quad_segs, workers=workers)
    seg, width, _, _, bounds, _ = layer_beads(g, settings=settings,
                                              filament_diameter=filament_diameter)
    good = np.isfinite(width) & (width > 0)
    per_layer = [np.flatnonzero(good[bounds[k]:bounds[k + 1]]) + bounds[k]
                 for k in range(len(g.layers))]
    r_max = float(width[good].max()) / 2 if good.any() else 0.0
    if not interior and _union_edges(r_max, tolerance) <= 256:
        with_target = [k for k in range(len(g.layers)) if per_layer[k].size]
        if not with_target:
            return iter(())
        lo, hi = _layer_boxes(seg, width, per_layer, with_target, tolerance, planned, reach)
        tiling = tile_layers(lo, hi, [per_layer[k].size for k in with_target],
                             gap=_TILE_GAP, max_area=_BATCH_AREA, max_weight=_BATCH_BEADS)

        kind = _layer_kinds(seg, width, per_layer, with_target, planned)

        def one(b: int) -> tuple[list[int], np.ndarray, object, list[float], bool]:
            first, stop = int(tiling.bounds[b]), int(tiling.bounds[b + 1])
            layers = with_target[first:stop]
            # a layer identical to an earlier one of the batch is planned on that one's tile
            _, at, inverse = np.unique(kind[first:stop], return_index=True, return_inverse=True)
            tile = at[inverse]
            own = np.flatnonzero(tile == np.arange(len(layers)))
            rows = np.concatenate([per_layer[layers[j]] for j in own])
            shift = np.repeat(tiling.offset[first + own], [per_layer[layers[j]].size for j in own],
                              axis=0)
            s = take_rows(seg, rows)
            u = bead_union(np.column_stack([s["x0"], s["y0"]]) + shift,
                           np.column_stack([s["x1"], s["y1"]]) + shift, width[rows] / 2,
                           grow=tolerance, workers=workers if b == 0 else 1)
            areas = _tile_areas(u, tiling, b, tolerance)
            return (layers, tiling.offset[first + tile], u, [areas[j] for j in tile],
                    b == tiling.batches - 1)

        todo = list(range(tiling.batches))
        if workers <= 1:
            return map(one, todo)
        return threaded(one, todo, workers)

    # GEOS: G, then G grown by the tolerance
    regions = [None] * len(g.layers)
    for li, geom, _facts in layer_regions(g, settings=settings,
                                          filament_diameter=filament_diameter,
                                          interior=interior):
        regions[li] = geom if geom is not None and not geom.is_empty else None
    todo_l = [k for k in range(len(g.layers)) if regions[k] is not None]

    def grown(k: int) -> tuple[list[int], np.ndarray, object, list[float], bool]:
        t = regions[k]
        return ([k], np.zeros((1, 2)), grown_target(t, tolerance), [float(t.area)],
                k == todo_l[-1])

    if workers <= 1:
        return map(grown, todo_l)
    return threaded(grown, todo_l, workers)


def _layer_kinds(seg, width, per_layer, layers, planned) -> np.ndarray:
    """Per layer (of ``layers``): a number shared by the layers with the very same beads and
    planned chords (to the bit), and by no other.

    Prismatic parts repeat layers (the calibration cube: 31 of its 100); such a layer's
    target, tile and footprint answers are its twin's, so its union is not built again.
    """
    pseg, porder, pbounds = planned
    seen: dict[tuple[bytes, bytes], int] = {}
    out = np.empty(len(layers), dtype=np.int64)
    for j, k in enumerate(layers):
        rows = per_layer[k]
        mine = porder[pbounds[k]:pbounds[k + 1]]
        key = (np.column_stack([seg["x0"][rows], seg["y0"][rows], seg["x1"][rows],
                                seg["y1"][rows], width[rows]]).tobytes(),
               np.column_stack([pseg["x0"][mine], pseg["y0"][mine], pseg["x1"][mine],
                                pseg["y1"][mine]]).tobytes())
        out[j] = seen.setdefault(key, len(seen))
    return out


def _layer_boxes(seg, width, per_layer, layers, tolerance, planned, reach):
    """Per layer: the box of its beads grown by their radius and the tolerance, and of its
    planned chords grown by ``reach`` (mm): all its footprints and bead polygons.

    One pass over all the layers (min and max are exact, so the order they are taken in
    does not matter; a loop per layer cost more than the bead union on small layers).
    """
    pseg, porder, pbounds = planned
    n = len(layers)
    lo = np.empty((n, 2))
    hi = np.empty((n, 2))
    if n == 0:
        return lo, hi
    sizes = np.array([per_layer[k].size for k in layers], dtype=np.int64)
    rows = np.concatenate([per_layer[k] for k in layers])
    first = np.cumsum(sizes) - sizes  # every layer here has beads
    s = take_rows(seg, rows)
    grow = width[rows] / 2 + tolerance
    for c, (a, b) in enumerate((("x0", "x1"), ("y0", "y1"))):
        lo[:, c] = np.minimum.reduceat(np.minimum(s[a], s[b]) - grow, first)
        hi[:, c] = np.maximum.reduceat(np.maximum(s[a], s[b]) + grow, first)
    # the planned chords of each layer (chords of unknown position are no extrusions:
    # kept out of the box all the same)
    lay = np.asarray(layers, dtype=np.int64)
    pb = np.asarray(pbounds, dtype=np.int64)
    a0, a1 = pb[lay], pb[lay + 1]
    count = a1 - a0
    some = np.flatnonzero(count > 0)
    if some.size:
        take = np.concatenate([porder[a0[j]:a1[j]] for j in some])
        q = take_rows(pseg, take)
        ok = (np.isfinite(q["x0"]) & np.isfinite(q["y0"]) & np.isfinite(q["x1"])
              & np.isfinite(q["y1"]))
        starts = np.cumsum(count[some]) - count[some]
        for c, (a, b) in enumerate((("x0", "x1"), ("y0", "y1"))):
            qlo = np.where(ok, np.minimum(q[a], q[b]) - reach, np.inf)
            qhi = np.where(ok, np.maximum(q[a], q[b]) + reach, -np.inf)
            lo[some, c] = np.minimum(lo[some, c], np.minimum.reduceat(qlo, starts))
            hi[some, c] = np.maximum(hi[some, c], np.maximum.reduceat(qhi, starts))
    return lo, hi


def _tile_areas(u, tiling, batch: int, tolerance: float) -> list[float]:
    """The area of G of each layer of a batch, mm²: its tile's part of the union (Green's
    theorem over the boundary pieces in the tile, about the tile's corner) less how far
    each piece stands out of G (:data:`~printability.planning.beadunion.SIDE` × ``tolerance``
    and, on a polygon's side, its ``beyond``) × its length."""
    n = int(tiling.bounds[batch + 1] - tiling.bounds[batch])
    if len(u.ex0) == 0:
        return [0.0] * n
    px, py = (float(v) for v in tiling.pitch[batch])
    twice, perimeter, out, ok = _tile_sums(u.ex0, u.ey0, u.ex1, u.ey1, u.beyond, px, py,
                                           int(tiling.cols[batch]), n)
    if not ok:
        raise RuntimeError("a boundary piece of the bead union lies outside every tile")
    area = np.abs(0.5 * twice)
    return np.maximum(0.0, area - SIDE * tolerance * perimeter - out).tolist()


@numba.njit(cache=True, nogil=True)
def _tile_sums(ex0, ey0, ex1, ey1, beyond, px, py, cols, n):  # pragma: no cover
    """Per tile (:func:`~printability.planning.tiles.tile_index` of each piece's midpoint):
    twice the signed area of its pieces about the tile's corner, their length and the sum
    of their lengths × ``beyond``, summed in the pieces' order (one pass); and whether
    every piece lies in a tile."""
    twice = np.zeros(n)
    length = np.zeros(n)
    out = np.zeros(n)
    for e in range(len(ex0)):
        j = tile_index((ex0[e] + ex1[e]) / 2, (ey0[e] + ey1[e]) / 2, px, py, cols, n)
        if j < 0:
            return twice, length, out, False
        ox = (j % cols) * px
        oy = (j // cols) * py
        x0 = ex0[e] - ox
        y0 = ey0[e] - oy
        x1 = ex1[e] - ox
        y1 = ey1[e] - oy
        twice[j] += x0 * y1 - x1 * y0
        piece = math.hypot(x1 - x0, y1 - y0)
        length[j] += piece
        out[j] += piece * beyond[e]
    return twice, length, out, True


def _union_edges(r: float, tolerance: float) -> float:
    """Edges per half turn of the widest bead's polygon in the bead union (inf: the
    tolerance is too small for it)."""
    rho, rmax = r + SIDE * tolerance, r * INNER + tolerance
    if not (tolerance > 0 and rho < rmax):
        return math.inf
    return math.ceil(math.pi / (2 * math.acos(rho / rmax)))


def threaded(fn, items: list, workers: int):
    """``map(fn, items)`` on ``workers`` threads, running at most ``workers + 1`` items
    ahead of the consumer (the kernels release the GIL): targets are built while the
    planner works, and no more of them are held than that."""
    it = iter(items)
    with ThreadPoolExecutor(workers) as ex:
        queue = deque(ex.submit(fn, item) for item in itertools.islice(it, workers + 1))
        while queue:
            # the next item is submitted once the consumer is done with this one: while it
            # holds one result, `workers` more are at most built or held (the refill before
            # the yield let workers + 2 start, which the test caught on a busy machine)
            yield queue.popleft().result()
            for item in itertools.islice(it, 1):
                queue.append(ex.submit(fn, item))

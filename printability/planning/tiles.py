"""Lay many layers side by side in one plane, so that one target serves them all.

The orientation planner answers each query with compiled kernels over one
target (a bead union and its grids); called once per layer, its fixed cost
per call (array set-up, a dozen kernel launches) outweighs the kernels on
parts with many small layers (the calibration cube: 100 layers of about 50
moves, two thirds of the planner's time). Layers are therefore planned in
batches: each layer of a batch is translated into a tile of its own, the
tiles are disjoint, and one target is built from all the translated beads.

Why the answers are those of one layer at a time: a layer's tile holds the
box of its beads grown by their radius and tolerance and the box of its
planned moves grown by the nozzle's radius, plus a gap. Every swept
footprint of the layer lies in its tile and every bead of another layer
outside it, so no footprint can meet another layer's target: it is accepted
or refused exactly as against its own layer's. The translation rounds the
coordinates by at most half an ulp of the batch's extent (tiles are laid
from the origin and a batch covers at most ``max_area``: 6e-14 mm for
500 mm), far inside the kernels' ε = 1e-9 mm.

Conventions: boxes as ``(n, 2)`` arrays of lower and upper corners, mm;
a layer ``j`` of a batch sits at tile ``(j % cols, j // cols)`` of size
``pitch``; its translation is ``offset[j]`` (added to its coordinates).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.errors import InputError

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["Tiling", "tile_index", "tile_layers"]


@dataclass(frozen=True, eq=False)
class Tiling:
    """Layers in batches, each layer translated into a tile of its batch.

    Attributes
    ----------
    bounds
        (nb + 1,) batch ``b`` holds the layers ``bounds[b]:bounds[b + 1]`` (in the order
        given to :func:`tile_layers`).
    offset
        (n, 2) translation of each layer, mm.
    pitch
        (nb, 2) tile size of each batch, mm.
    cols
        (nb,) tiles per row of each batch.
    """

    bounds: np.ndarray
    offset: np.ndarray
    pitch: np.ndarray
    cols: np.ndarray

    @property
    def batches(self) -> int:
        return len(self.bounds) - 1

    def tile_of(self, batch: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The tile (index within ``batch``: its layer's, -1 outside every tile) of
        translated points (:func:`tile_index`)."""
        px, py = (float(v) for v in self.pitch[batch])
        n = int(self.bounds[batch + 1] - self.bounds[batch])
        return _tiles_of(np.ascontiguousarray(x, dtype=float).reshape(-1),
                         np.ascontiguousarray(y, dtype=float).reshape(-1), px, py,
                         int(self.cols[batch]), n)


@numba.njit(cache=True, nogil=True)
def tile_index(x, y, px, py, cols, n):  # pragma: no cover
    """The tile of the point (x, y) in a batch of ``n`` tiles of ``pitch`` (px, py) laid
    ``cols`` to a row, -1 outside every tile: the one rule for which tile a point is in."""
    ix = math.floor(x / px)
    iy = math.floor(y / py)
    j = iy * cols + ix
    return j if 0 <= ix < cols and iy >= 0 and j < n else -1


@numba.njit(cache=True, nogil=True)
def _tiles_of(x, y, px, py, cols, n):  # pragma: no cover
    out = np.empty(len(x), np.int64)
    for i in range(len(x)):
        out[i] = tile_index(x[i], y[i], px, py, cols, n)
    return out


def tile_layers(lo: np.ndarray, hi: np.ndarray, weight: np.ndarray, *, gap: float,
                max_area: float, max_weight: float) -> Tiling:
    """Group consecutive layers into batches and give each layer its tile.

    Parameters
    ----------
    lo, hi
        (n, 2) each layer's box (everything its footprints and beads can reach), mm.
    weight
        (n,) what a layer costs in memory (its bead count, say).
    gap
        Space between tiles, mm (> 0).
    max_area
        A batch closes before its tiles would cover more than this, mm² (a layer larger
        than that is a batch of its own).
    max_weight
        A batch closes before its weight would pass this.

    Complexity: O(n).
    """
    lo = np.asarray(lo, dtype=float).reshape(-1, 2)
    hi = np.asarray(hi, dtype=float).reshape(-1, 2)
    weight = np.asarray(weight, dtype=float).reshape(-1)
    n = len(lo)
    if len(hi) != n or len(weight) != n:
        raise InputError("tile_layers: lo, hi and weight must have one row per layer")
    if not (gap > 0 and math.isfinite(gap)):
        raise InputError(f"tile_layers: the gap between tiles must be positive; got {gap!r}")
    if n and not (np.isfinite(lo).all() and np.isfinite(hi).all() and (hi >= lo).all()):
        raise InputError("tile_layers: every layer needs a finite, non-empty box")
    size = hi - lo
    bounds = [0]
    pitches: list[tuple[float, float]] = []
    wmax = hmax = total = 0.0
    for j in range(n):
        w2, h2 = max(wmax, size[j, 0]), max(hmax, size[j, 1])
        count = j - bounds[-1] + 1
        if count > 1 and ((w2 + gap) * (h2 + gap) * count > max_area
                          or total + weight[j] > max_weight):
            pitches.append((wmax + gap, hmax + gap))
            bounds.append(j)
            w2, h2, total = size[j, 0], size[j, 1], 0.0
        wmax, hmax = w2, h2
        total += weight[j]
    if n:
        pitches.append((wmax + gap, hmax + gap))
        bounds.append(n)
    b = np.asarray(bounds, dtype=np.int64)
    pitch = np.asarray(pitches, dtype=float).reshape(-1, 2)
    counts = np.diff(b)
    cols = np.maximum(1, np.ceil(np.sqrt(counts))).astype(np.int64)
    batch = np.repeat(np.arange(len(counts)), counts)
    pos = np.arange(n) - b[:-1][batch]
    col, row = pos % cols[batch], pos // cols[batch]
    origin = np.column_stack([col, row]) * pitch[batch] + gap / 2
    return Tiling(bounds=b, offset=origin - lo, pitch=pitch, cols=cols)

"""Connected components of the motion restriction P in configuration space.

P lives in R² × (angles). It is sampled at angles φ_0 < φ_1 < ...; at each
angle P_φk splits into XY pieces (polygons, or labelled raster blobs). A
piece at φ_k and a piece at φ_k+1 are joined when they overlap in XY — the
discrete version of continuity in φ; on a full turn the last angle wraps to
the first. Connected components of that graph (networkx) are the components
of P. On XY there is one angle and the components are the pieces.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TypeVar

import networkx as nx
import numpy as np

__all__ = ["component_labels"]

T = TypeVar("T")


def component_labels(
    pieces: Sequence[Sequence[T]],
    overlap: Callable[[int, T, int, T], bool],
    *,
    wrap: bool,
) -> list[list[int]]:
    """Label every piece with the index of its configuration-space component.

    Parameters
    ----------
    pieces
        ``pieces[k]`` are the XY pieces of P at the k-th sampled angle.
    overlap
        ``overlap(k, a, k2, b)`` tells whether piece ``a`` at angle k and
        piece ``b`` at angle k2 (= k + 1, or 0 when wrapping) overlap in XY.
    wrap
        Join the last angle to the first (full-turn rotary axis).

    Returns
    -------
    list of list of int
        ``labels[k][i]``: component of piece i at angle k, numbered 0..n-1 in
        order of first appearance.

    Notes
    -----
    Cost: one ``overlap`` call per pair of pieces at consecutive angles, so
    O(Σ_k |pieces_k|·|pieces_k+1|) calls; callers use bounding boxes to make
    each call cheap.
    """
    g = nx.Graph()
    n = len(pieces)
    for k in range(n):
        g.add_nodes_from((k, i) for i in range(len(pieces[k])))
    pairs = [(k, k + 1) for k in range(n - 1)]
    if wrap and n > 2:
        pairs.append((n - 1, 0))
    for k, k2 in pairs:
        for i, a in enumerate(pieces[k]):
            for j, b in enumerate(pieces[k2]):
                if overlap(k, a, k2, b):
                    g.add_edge((k, i), (k2, j))
    labels = [[-1] * len(p) for p in pieces]
    comps = sorted(nx.connected_components(g), key=lambda c: min(c))
    for c_id, comp in enumerate(comps):
        for k, i in comp:
            labels[k][i] = c_id
    return labels


def angle_ranges(labels: list[list[int]], angles: np.ndarray) -> list[tuple[float, float]]:
    """(min, max) sampled angle of each component, degrees."""
    count = 1 + max((max(row) for row in labels if row), default=-1)
    lo = [np.inf] * count
    hi = [-np.inf] * count
    for k, row in enumerate(labels):
        for c in row:
            lo[c] = min(lo[c], float(angles[k]))
            hi[c] = max(hi[c], float(angles[k]))
    return list(zip(lo, hi, strict=True))

"""The records the band settling's compiled kernels take (:mod:`printability.mmc._band`).

Each is a :class:`~typing.NamedTuple` of arrays and scalars, which numba passes as one
argument at no cost; :mod:`printability.mmc._band` fills them, the kernels of
``_band_lists``, ``_band_lower`` and ``_band_settle`` read them. World coordinates, mm.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["BandPixels", "ChainModel", "ClipBuffers", "PieceArrays", "PixelLists", "Rings"]


class BandPixels(NamedTuple):
    """The uncertain pixels and the raster they lie on.

    Attributes
    ----------
    pix_i, pix_j
        ``int64 (n,)``: row and column of each uncertain pixel.
    cls, cov, outer
        ``(ny, nx)``: the raster's classification, covered fractions and outer S.
    x0, y0, h
        The grid's origin and spacing.
    """

    pix_i: np.ndarray
    pix_j: np.ndarray
    cls: np.ndarray
    cov: np.ndarray
    outer: np.ndarray
    x0: float
    y0: float
    h: float


class Rings(NamedTuple):
    """∂G's edges ``(m, 4)`` [ax, ay, bx, by] and the previous and next edge on each ring."""

    edges: np.ndarray
    prev_: np.ndarray
    next_: np.ndarray


class PixelLists(NamedTuple):
    """Per uncertain pixel, CSR lists (``ptr``, ``idx``) of what can matter there.

    Attributes
    ----------
    eptr, eidx
        The edges within eps of the closed pixel (the classification's cut test).
    nptr, nidx
        The edges within the chain model's reach of it.
    pptr, pidx
        The pieces whose bounding box meets it (quads first, then caps numbered from the
        number of quads).
    """

    eptr: np.ndarray
    eidx: np.ndarray
    nptr: np.ndarray
    nidx: np.ndarray
    pptr: np.ndarray
    pidx: np.ndarray


class PieceArrays(NamedTuple):
    """The certified pieces: ``quads (q, 8)``, ``quad_edge (q,)``, ``caps (c, 6)`` (as in
    :class:`printability.mmc._band.BandPieces`)."""

    quads: np.ndarray
    quad_edge: np.ndarray
    caps: np.ndarray


class ChainModel(NamedTuple):
    """The convex chain model of the lower bound (:func:`printability.mmc._band.settle_band`).

    Attributes
    ----------
    cells
        ``(k, 6)`` per angle cell: L⁻¹ (row-major), the footprint's total angle and the
        cell's half-width, radians.
    a, b
        The footprint's semi-axes (a ≥ b).
    delta
        How far the footprint's boundary moves within half a cell.
    reach
        Edges farther than this from a leaf cannot bound a footprint that covers it.
    """

    cells: np.ndarray
    a: float
    b: float
    delta: float
    reach: float


class ClipBuffers(NamedTuple):
    """Work arrays of the chain model's polygon clipping (each ≥ chain length + 8)."""

    wx: np.ndarray
    wy: np.ndarray
    vx: np.ndarray
    vy: np.ndarray

"""Per-pixel lists of the band settling (:mod:`printability.mmc._band`), in CSR form.

Each kernel runs twice: with ``count_only`` it counts into ``ptr[u + 1]`` what each
uncertain pixel u (``pix_index[i, j] = u``, −1 for other pixels) gets; the caller turns the
counts into offsets and the second run fills ``out``.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["TILE", "bucket_pieces", "edge_pixels"]

TILE = 4  # log2 of the tile side, pixels, of the bucketing's occupancy map


@nb.njit(cache=True)
def bucket_pieces(quads, caps, pix_index, tiles, x0, y0, h, ny, nx, count_only, ptr, out):
    # pragma: no cover - numba
    """Pieces whose bounding box meets each uncertain pixel (CSR over ``pix_index``);
    ``tiles`` marks the 2^TILE-pixel tiles that hold such a pixel."""
    nq = quads.shape[0]
    fill = ptr.copy() if not count_only else ptr
    for p in range(nq + caps.shape[0]):
        if p < nq:
            mnx = min(quads[p, 0], quads[p, 2], quads[p, 4], quads[p, 6])
            mxx = max(quads[p, 0], quads[p, 2], quads[p, 4], quads[p, 6])
            mny = min(quads[p, 1], quads[p, 3], quads[p, 5], quads[p, 7])
            mxy = max(quads[p, 1], quads[p, 3], quads[p, 5], quads[p, 7])
        else:
            c = p - nq
            # L = inverse of the stored L⁻¹: half-widths of the ellipse's box are the
            # row norms of L
            a00, a01, a10, a11 = caps[c, 2], caps[c, 3], caps[c, 4], caps[c, 5]
            det = a00 * a11 - a01 * a10
            l00, l01, l10, l11 = a11 / det, -a01 / det, -a10 / det, a00 / det
            wx = math.sqrt(l00 * l00 + l01 * l01)
            wy = math.sqrt(l10 * l10 + l11 * l11)
            mnx = caps[c, 0] - wx
            mxx = caps[c, 0] + wx
            mny = caps[c, 1] - wy
            mxy = caps[c, 1] + wy
        j0 = max(int(np.floor((mnx - x0) / h)), 0)
        j1 = min(int(np.floor((mxx - x0) / h)), nx - 1)
        i0 = max(int(np.floor((mny - y0) / h)), 0)
        i1 = min(int(np.floor((mxy - y0) / h)), ny - 1)
        for ti in range(i0 >> TILE, (i1 >> TILE) + 1):
            for tj in range(j0 >> TILE, (j1 >> TILE) + 1):
                if not tiles[ti, tj]:
                    continue  # no pixel to settle in this tile
                for i in range(max(i0, ti << TILE), min(i1, ((ti + 1) << TILE) - 1) + 1):
                    for j in range(max(j0, tj << TILE), min(j1, ((tj + 1) << TILE) - 1) + 1):
                        u = pix_index[i, j]
                        if u < 0:
                            continue
                        if count_only:
                            ptr[u + 1] += 1
                        else:
                            out[fill[u]] = p
                            fill[u] += 1


@nb.njit(cache=True)
def edge_pixels(edges, pix_index, x0, y0, h, ny, nx, eps, count_only, ptr, out):
    # pragma: no cover - numba
    """Edges within eps of each uncertain pixel (CSR), as the classification's cut test."""
    fill = ptr.copy() if not count_only else ptr
    for e in range(edges.shape[0]):
        ax, ay, bx, by = edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3]
        i0 = max(int(np.floor((min(ay, by) - eps - y0) / h)), 0)
        i1 = min(int(np.floor((max(ay, by) + eps - y0) / h)), ny - 1)
        for i in range(i0, i1 + 1):
            bl = y0 + i * h - eps
            bh = y0 + (i + 1) * h + eps
            if ay == by:
                xa, xb = ax, bx
            else:
                ta = min(max((bl - ay) / (by - ay), 0.0), 1.0)
                tb = min(max((bh - ay) / (by - ay), 0.0), 1.0)
                xa = ax + ta * (bx - ax)
                xb = ax + tb * (bx - ax)
            if xa > xb:
                xa, xb = xb, xa
            j0 = max(int(np.floor((xa - eps - x0) / h)), 0)
            j1 = min(int(np.floor((xb + eps - x0) / h)), nx - 1)
            for j in range(j0, j1 + 1):
                u = pix_index[i, j]
                if u < 0:
                    continue
                if count_only:
                    ptr[u + 1] += 1
                else:
                    out[fill[u]] = e
                    fill[u] += 1

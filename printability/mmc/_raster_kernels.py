"""Numba kernels of the raster MMC engine: packing, rasterising, bit morphology.

See :mod:`printability.mmc.raster` for the engine; the run-length kernels (labels,
boundaries) are in :mod:`printability.mmc._raster_runs` and the band settling's in the
``_band_*`` modules.

Bit layout: a mask on a Grid of ``ny × nx`` pixels is a ``uint64`` array of
shape ``(ny, nw)``, ``nw = ceil(nx / 64)``; pixel ``[i, j]`` is bit ``j % 64``
(least significant first) of word ``[i, j // 64]``. Bits past ``nx`` are 0.

Why these are written here rather than taken from a library: OpenCV and
scipy.ndimage work on one byte per pixel over the whole image and cannot be
told that most of the image needs no work; these kernels work on 64 pixels
per machine word, touch only the words of a band near ∂G, and stop a word as
soon as its answer is known (an erosion word that reached 0, a dilation word
that covers every pixel still missing). The polygon rasteriser is conservative
(every pixel the boundary comes within ``eps`` of is flagged), which no
library rasteriser promises, and the coverage accumulator gives exact
per-pixel areas for all pixels in one sweep.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from numba.cpython.unsafe.numbers import trailing_zeros

from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = [
    "ALL_ONES",
    "build_tables",
    "classify_rings",
    "count_bits_into",
    "coverage_rings",
    "dilate_words",
    "erode_words",
    "flat_runs",
    "near_needy",
    "pack_bits",
    "table_padding",
    "unpack_bits",
    "update_tables",
]

ALL_ONES = np.uint64(0xFFFFFFFFFFFFFFFF)
_U0 = np.uint64(0)
_U1 = np.uint64(1)

# --------------------------------------------------------------------------- packing


def pack_bits(mask: np.ndarray) -> np.ndarray:
    """Pack a boolean ``(ny, nx)`` array into ``uint64 (ny, ceil(nx/64))`` (LSB first)."""
    ny, nx = mask.shape
    nw = (nx + 63) // 64
    by = np.packbits(mask.astype(np.bool_, copy=False), axis=1, bitorder="little")
    out = np.zeros((ny, nw * 8), np.uint8)
    out[:, : by.shape[1]] = by
    return out.view("<u8").astype(np.uint64, copy=False).reshape(ny, nw)


def unpack_bits(bits: np.ndarray, nx: int) -> np.ndarray:
    """Inverse of :func:`pack_bits`: boolean ``(..., ny, nx)``."""
    b8 = np.ascontiguousarray(bits).astype("<u8", copy=False).view(np.uint8)
    return np.unpackbits(b8, axis=-1, bitorder="little", count=nx).astype(bool)


# --------------------------------------------------------------------------- rasterising


@nb.njit(cache=True)
def classify_rings(xs, ys, starts, x0, y0, h, nx, ny, eps):  # pragma: no cover - numba
    """Conservative classification of the pixels of a grid against polygon rings.

    Returns ``uint8 (ny, nx)``: 0 the closed pixel lies outside, 3 inside (no
    boundary within ``eps`` of the closed pixel, centre inside by even-odd
    parity), 1 or 2 cut (the boundary comes within ``eps`` of the closed
    pixel), 2 when its centre is inside by parity. Rings are concatenated in
    ``xs, ys`` (each closed: last point = first) with ``starts`` offsets.
    Cost O(Σ pixels cut + Σ rows crossed + nx·ny).
    """
    cut = np.zeros((ny, nx), np.uint8)
    tog = np.zeros((ny, nx + 1), np.uint8)
    nr = starts.shape[0] - 1
    for r in range(nr):
        for p in range(starts[r], starts[r + 1] - 1):
            ax, ay, bx, by = xs[p], ys[p], xs[p + 1], ys[p + 1]
            # --- cut pixels: rows spanned by the segment grown by eps
            ylo = min(ay, by) - eps
            yhi = max(ay, by) + eps
            i0 = int(np.floor((ylo - y0) / h))
            i1 = int(np.floor((yhi - y0) / h))
            if i0 < 0:
                i0 = 0
            if i1 > ny - 1:
                i1 = ny - 1
            for i in range(i0, i1 + 1):
                bl = y0 + i * h - eps
                bh = y0 + (i + 1) * h + eps
                if ay == by:
                    xa, xb = ax, bx
                else:
                    ta = (bl - ay) / (by - ay)
                    tb = (bh - ay) / (by - ay)
                    ta = min(max(ta, 0.0), 1.0)
                    tb = min(max(tb, 0.0), 1.0)
                    xa = ax + ta * (bx - ax)
                    xb = ax + tb * (bx - ax)
                if xa > xb:
                    xa, xb = xb, xa
                j0 = int(np.floor((xa - eps - x0) / h))
                j1 = int(np.floor((xb + eps - x0) / h))
                if j0 < 0:
                    j0 = 0
                if j1 > nx - 1:
                    j1 = nx - 1
                for j in range(j0, j1 + 1):
                    cut[i, j] = 1
            # --- parity: crossings of the row-centre lines (half-open in y)
            if ay == by:
                continue
            lo_y, hi_y = min(ay, by), max(ay, by)
            # one row of slack each side; the exact test below decides with the same
            # float row centre yc for every edge, so a vertex is counted exactly once
            c0 = int(np.ceil((lo_y - y0) / h - 0.5)) - 1
            c1 = int(np.ceil((hi_y - y0) / h - 0.5))
            if c0 < 0:
                c0 = 0
            if c1 > ny - 1:
                c1 = ny - 1
            for i in range(c0, c1 + 1):
                yc = y0 + (i + 0.5) * h
                if yc < lo_y or yc >= hi_y:
                    continue
                xc = ax + (yc - ay) * (bx - ax) / (by - ay)
                j = int(np.floor((xc - x0) / h - 0.5)) + 1
                if j < 0:
                    j = 0
                if j <= nx:
                    tog[i, j] ^= 1
    out = np.zeros((ny, nx), np.uint8)
    for i in range(ny):
        par = 0
        for j in range(nx):
            par ^= tog[i, j]
            if cut[i, j]:
                out[i, j] = 2 if par else 1
            elif par:
                out[i, j] = 3
    return out


@nb.njit(cache=True)
def coverage_rings(xs, ys, starts, x0, y0, h, nx, ny):  # pragma: no cover - numba
    """Exact signed area of the rings inside every pixel, as a fraction of h².

    The signed-area accumulation of scanline font rasterisers: each edge adds
    to a per-row buffer the exact area it sweeps in each pixel, and a prefix
    sum along the row yields the covered fraction (with the sign of the ring
    orientation, so shells and holes of opposite orientation sum correctly).
    Exact up to floating-point rounding. Cost O(Σ pixels crossed + nx·ny).
    """
    acc = np.zeros((ny, nx + 2))
    nr = starts.shape[0] - 1
    for r in range(nr):
        for p in range(starts[r], starts[r + 1] - 1):
            px0 = (xs[p] - x0) / h
            py0 = (ys[p] - y0) / h
            px1 = (xs[p + 1] - x0) / h
            py1 = (ys[p + 1] - y0) / h
            if py0 == py1:
                continue
            if py0 < py1:
                d = 1.0
            else:
                d = -1.0
                px0, py0, px1, py1 = px1, py1, px0, py0
            dxdy = (px1 - px0) / (py1 - py0)
            x = px0
            ystart = int(np.floor(py0))
            yend = int(np.ceil(py1))
            if ystart < 0:
                x = px0 - py0 * dxdy
                ystart = 0
            if yend > ny:
                yend = ny
            for y in range(ystart, yend):
                dy = min(y + 1.0, py1) - max(float(y), py0)
                xnext = x + dxdy * dy
                dd = dy * d
                if x < xnext:
                    xa, xb = x, xnext
                else:
                    xa, xb = xnext, x
                xaf = np.floor(xa)
                xai = int(xaf)
                xbi = int(np.ceil(xb))
                if xai < 0:  # cannot happen for rings inside the grid; keep memory safe
                    xai = 0
                if xbi > nx:
                    xbi = nx
                if xbi <= xai + 1:
                    xmf = 0.5 * (x + xnext) - xaf
                    acc[y, xai] += dd - dd * xmf
                    acc[y, xai + 1] += dd * xmf
                else:
                    s = 1.0 / (xb - xa)
                    x0f = xa - xaf
                    a0 = 0.5 * s * (1.0 - x0f) * (1.0 - x0f)
                    x1f = xb - xbi + 1.0
                    am = 0.5 * s * x1f * x1f
                    acc[y, xai] += dd * a0
                    if xbi == xai + 2:
                        acc[y, xai + 1] += dd * (1.0 - a0 - am)
                    else:
                        a1 = s * (1.5 - x0f)
                        acc[y, xai + 1] += dd * (a1 - a0)
                        for xi in range(xai + 2, xbi - 1):
                            acc[y, xi] += dd * s
                        a2 = a1 + (xbi - xai - 3) * s
                        acc[y, xbi - 1] += dd * (1.0 - a2 - am)
                    acc[y, xbi] += dd * am
                x = xnext
    out = np.empty((ny, nx))
    for i in range(ny):
        c = 0.0
        for j in range(nx):
            c += acc[i, j]
            out[i, j] = c
    return out


# --------------------------------------------------------------------------- bit morphology


def table_padding(radius: int) -> tuple[int, int]:
    """(rows, words) of zero padding the tables need for kernels of half-size ``radius``."""
    return radius + 1, radius // 64 + 2


@nb.njit(cache=True)
def build_tables(bits, tables, pad_rows, pad_words, op_and, row_lo, row_hi
                 ):  # pragma: no cover - numba
    """Doubling tables of a bit array: ``tables[l][i, j] = op_{t<2^l} bits[i, j + t]``.

    ``tables`` is padded by ``pad_rows`` rows and ``pad_words`` words on each
    side (left zero). ``op_and`` selects AND (erosion) or OR (dilation); level
    0 is a copy. A run of any length L is then two reads: the level of the
    largest power of two m ≤ L at j and at j + L − m. Only rows
    ``row_lo <= i < row_hi`` are (re)built. Cost O(levels · rows · nw).
    """
    nlev = tables.shape[0]
    nw = bits.shape[1]
    for i in range(row_lo, row_hi):
        for w in range(nw):
            tables[0, i + pad_rows, w + pad_words] = bits[i, w]
    for lev in range(1, nlev):
        sh = np.uint64(1 << (lev - 1))
        back = np.uint64(64 - (1 << (lev - 1)))
        for i in range(row_lo + pad_rows, row_hi + pad_rows):
            for w in range(pad_words, pad_words + nw):
                cur = tables[lev - 1, i, w]
                v = (cur >> sh) | (tables[lev - 1, i, w + 1] << back)
                if op_and:
                    tables[lev, i, w] = cur & v
                else:
                    tables[lev, i, w] = cur | v


def flat_runs(runs: np.ndarray, table_shape: tuple[int, int, int], pad_rows: int,
              pad_words: int) -> np.ndarray:
    """Runs ``(dy, a, level, second)`` as flat table offsets for :func:`erode_words`.

    A run read at word (i, w) starts at column 64·(w + pad_words) + a of padded
    row i + pad_rows + dy: the word offset and the bit shift depend on the run
    only, so each read is one add and two loads. Returns ``int64 (nr, 4)``:
    offset, shift, second offset (−1 when none), second shift.
    """
    _, nyp, nwp = table_shape
    out = np.empty((len(runs), 4), np.int64)
    if len(runs) == 0:
        return out
    dy, a, lev, second = runs[:, 0], runs[:, 1], runs[:, 2], runs[:, 3]
    base = lev * nyp * nwp + (pad_rows + dy) * nwp + pad_words
    out[:, 0] = base + (a >> 6)
    out[:, 1] = a & 63
    a2 = a + np.maximum(second, 0)
    out[:, 2] = np.where(second >= 0, base + (a2 >> 6), -1)
    out[:, 3] = a2 & 63
    return out


@nb.njit(cache=True, inline="always")
def _flat_read(t, f, s):  # pragma: no cover - numba
    sh = np.uint64(s)
    return (t[f] >> sh) | ((t[f + 1] << _U1) << (np.uint64(63) - sh))


@nb.njit(cache=True)
def erode_words(tflat, nwp, fr, band_i, band_w, last_mask, out_work,
                out_vals):  # pragma: no cover - numba
    """Erosion (AND over kernel runs) of the words listed in the band.

    ``tflat`` is the flattened padded AND-table (rows of ``nwp`` words) and
    ``fr`` the runs from :func:`flat_runs`. The result of band word b = (i, w)
    goes to ``out_work[i, w]`` and ``out_vals[b]`` (when ``out_vals`` is
    non-empty). A word stops at 0.
    """
    nw = out_work.shape[1]
    nr = fr.shape[0]
    store = out_vals.shape[0] > 0
    for b in range(band_i.shape[0]):
        i = band_i[b]
        w = band_w[b]
        base = i * nwp + w
        acc = ALL_ONES
        for r in range(nr):
            v = _flat_read(tflat, fr[r, 0] + base, fr[r, 1])
            if fr[r, 2] >= 0:
                v &= _flat_read(tflat, fr[r, 2] + base, fr[r, 3])
            acc &= v
            if acc == _U0:
                break
        if w == nw - 1:
            acc &= last_mask
        out_work[i, w] = acc
        if store:
            out_vals[b] = acc


@nb.njit(cache=True)
def update_tables(bits, tables, pad_rows, pad_words, band_i, band_w, op_and
                  ):  # pragma: no cover - numba
    """Refresh doubling tables after the listed words of ``bits`` changed.

    A level-l entry of word w (2^l ≤ 64) depends on level-0 words w and w + 1
    only, so the words to redo are the listed ones and their left
    neighbours, level by level. Cost O(levels · listed words).
    """
    nlev = tables.shape[0]
    for b in range(band_i.shape[0]):
        tables[0, band_i[b] + pad_rows, band_w[b] + pad_words] = bits[band_i[b], band_w[b]]
    for lev in range(1, nlev):
        sh = np.uint64(1 << (lev - 1))
        back = np.uint64(64 - (1 << (lev - 1)))
        for b in range(band_i.shape[0]):
            i = band_i[b] + pad_rows
            for w in (band_w[b] + pad_words - 1, band_w[b] + pad_words):
                cur = tables[lev - 1, i, w]
                v = (cur >> sh) | (tables[lev - 1, i, w + 1] << back)
                if op_and:
                    tables[lev, i, w] = cur & v
                else:
                    tables[lev, i, w] = cur | v


@nb.njit(cache=True)
def dilate_words(tflat, nwp, fr, target, union):  # pragma: no cover - numba
    """OR into ``union`` the dilation (OR over kernel runs, reading the flattened padded
    OR-table) on the pixels of ``target`` not yet in ``union``.

    ``fr`` from :func:`flat_runs` (runs of at most 64 pixels, so
    :func:`update_tables` can keep the tables fresh). Words whose target
    pixels are all in ``union`` already are skipped (a union over angles
    needs nothing more there); a word stops as soon as it covers every
    missing pixel. Returns the number of words computed.
    """
    ny, nw = union.shape
    nr = fr.shape[0]
    done = 0
    for i in range(ny):
        for w in range(nw):
            tgt = target[i, w] & ~union[i, w]
            if tgt == _U0:
                continue
            done += 1
            base = i * nwp + w
            acc = _U0
            for r in range(nr):
                v = _flat_read(tflat, fr[r, 0] + base, fr[r, 1])
                if fr[r, 2] >= 0:
                    v |= _flat_read(tflat, fr[r, 2] + base, fr[r, 3])
                acc |= v
                if (acc & tgt) == tgt:
                    break
            union[i, w] |= acc & tgt
    return done


@nb.njit(cache=True)
def near_needy(target, union, band_i, band_w, ry, rw):  # pragma: no cover - numba
    """Indices of the band words within (ry rows, rw words) of a word whose target pixels
    are not all in ``union`` yet: the only P words a dilation can still read.

    Cost O(ny·nw + band) with a 2-D prefix sum over words.
    """
    ny, nw = union.shape
    pre = np.zeros((ny + 1, nw + 1), np.int32)
    for i in range(ny):
        run = 0
        for w in range(nw):
            if (target[i, w] & ~union[i, w]) != _U0:
                run += 1
            pre[i + 1, w + 1] = pre[i, w + 1] + run
    out = np.empty(band_i.shape[0], np.int64)
    m = 0
    for b in range(band_i.shape[0]):
        i0 = max(band_i[b] - ry, 0)
        i1 = min(band_i[b] + ry + 1, ny)
        w0 = max(band_w[b] - rw, 0)
        w1 = min(band_w[b] + rw + 1, nw)
        if pre[i1, w1] - pre[i0, w1] - pre[i1, w0] + pre[i0, w0] > 0:
            out[m] = b
            m += 1
    return out[:m]


@nb.njit(cache=True)
def count_bits_into(count, base, band_i, band_w, vals, n_angles):  # pragma: no cover - numba
    """``count[i, j]`` = number of angles whose mask holds pixel (i, j).

    Masks are ``base`` everywhere except at the band words, whose value per
    angle is ``vals[k, b]``. Cost O(set bits).
    """
    ny, nx = count.shape
    nw = base.shape[1]
    n16 = np.uint16(n_angles)
    for i in range(ny):
        for w in range(nw):
            v = base[i, w]
            if v == ALL_ONES and w * 64 + 64 <= nx:
                for t in range(64):
                    count[i, w * 64 + t] = n16
                continue
            while v != _U0:
                j = w * 64 + trailing_zeros(v)
                if j < nx:
                    count[i, j] = n16
                v &= v - _U1
    for b in range(band_i.shape[0]):
        i = band_i[b]
        w = band_w[b]
        j0 = w * 64
        for bit in range(64):
            if j0 + bit < nx:
                count[i, j0 + bit] = 0
        for k in range(vals.shape[0]):
            v = vals[k, b]
            while v != _U0:
                count[i, j0 + trailing_zeros(v)] += 1
                v &= v - _U1

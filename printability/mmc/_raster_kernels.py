"""Numba kernels of the raster MMC engine (see :mod:`printability.mmc.raster`).

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

import math

import numba as nb
import numpy as np
from numba.cpython.unsafe.numbers import trailing_zeros

from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = [
    "ALL_ONES",
    "boundary_segments",
    "build_tables",
    "classify_rings",
    "count_bits_into",
    "coverage_rings",
    "dilate_words",
    "erode_words",
    "extract_runs",
    "flat_runs",
    "label_runs",
    "near_needy",
    "overlap_pairs",
    "pack_bits",
    "pivot_centres",
    "slide_intervals",
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


# --------------------------------------------------------------------------- runs and labels


@nb.njit(cache=True)
def extract_runs(bits, nx):  # pragma: no cover - numba
    """Horizontal runs of set pixels: arrays (row, start, stop) sorted by row then start.

    Whole words of 0s or 1s are skipped; inside a mixed word the next transition
    is found with a trailing-zero count. Cost O(ny·nw + runs).
    """
    ny, nw = bits.shape
    n = 0
    rr = np.empty(0, np.int32)
    rs = np.empty(0, np.int32)
    re = np.empty(0, np.int32)
    for pass_ in range(2):
        if pass_ == 1:
            rr = np.empty(n, np.int32)
            rs = np.empty(n, np.int32)
            re = np.empty(n, np.int32)
            n = 0
        for i in range(ny):
            inrun = False
            start = 0
            for w in range(nw):
                v = bits[i, w]
                if v == _U0 and not inrun:
                    continue
                if v == ALL_ONES and inrun:
                    continue
                pos = 0
                while pos < 64:
                    if inrun:
                        z = (~v) >> np.uint64(pos)
                        if z == _U0:
                            break
                        pos += trailing_zeros(z)
                        if pass_ == 1:
                            rr[n] = i
                            rs[n] = start
                            re[n] = w * 64 + pos
                        n += 1
                        inrun = False
                    else:
                        o = v >> np.uint64(pos)
                        if o == _U0:
                            break
                        pos += trailing_zeros(o)
                        start = w * 64 + pos
                        inrun = True
            if inrun:
                if pass_ == 1:
                    rr[n] = i
                    rs[n] = start
                    re[n] = min(nw * 64, nx)
                n += 1
    return rr, rs, re


@nb.njit(cache=True)
def _find(parent, a):  # pragma: no cover - numba
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@nb.njit(cache=True)
def label_runs(rr, rs, re):  # pragma: no cover - numba
    """4-connected labels of runs (as ``scipy.ndimage.label``'s default structure).

    Two runs are joined when they lie on adjacent rows and share a column.
    Returns (labels numbered 0..n−1 in order of first run, count).
    """
    n = rr.shape[0]
    parent = np.arange(n)
    # rows start indices
    a = 0  # start of previous row's runs
    b = 0  # start of current row
    while b < n:
        cur_row = rr[b]
        e = b
        while e < n and rr[e] == cur_row:
            e += 1
        if a < b and rr[a] == cur_row - 1:
            p, q = a, b
            while p < b and q < e:
                if rs[p] < re[q] and rs[q] < re[p]:
                    x, y = _find(parent, p), _find(parent, q)
                    if x != y:
                        if x < y:
                            parent[y] = x
                        else:
                            parent[x] = y
                if re[p] < re[q]:
                    p += 1
                else:
                    q += 1
        a = b
        b = e
    labels = np.empty(n, np.int32)
    remap = -np.ones(n, np.int64)
    cnt = 0
    for t in range(n):
        root = _find(parent, t)
        if remap[root] < 0:
            remap[root] = cnt
            cnt += 1
        labels[t] = remap[root]
    return labels, cnt


@nb.njit(cache=True)
def overlap_pairs(r1, s1, e1, l1, r2, s2, e2, l2):  # pragma: no cover - numba
    """Label pairs (a, b), shape (m, 2), of two run sets that share a pixel (with repeats)."""
    n1, n2 = r1.shape[0], r2.shape[0]
    out = np.empty((n1 + n2, 2), np.int64)
    m = 0
    p, q = 0, 0
    while p < n1 and q < n2:
        if r1[p] < r2[q] or (r1[p] == r2[q] and e1[p] <= s2[q]):
            p += 1
            continue
        if r2[q] < r1[p] or (r1[p] == r2[q] and e2[q] <= s1[p]):
            q += 1
            continue
        out[m, 0] = l1[p]
        out[m, 1] = l2[q]
        m += 1
        if e1[p] < e2[q]:
            p += 1
        else:
            q += 1
    return out[:m]


@nb.njit(cache=True)
def _push(out, m, x0, y0, x1, y1):  # pragma: no cover - numba
    if m == out.shape[0]:
        grown = np.empty((2 * out.shape[0], 4))
        grown[:m] = out[:m]
        out = grown
    out[m, 0] = x0
    out[m, 1] = y0
    out[m, 2] = x1
    out[m, 3] = y1
    return out


@nb.njit(cache=True)
def boundary_segments(bits, nx):  # pragma: no cover - numba
    """Boundary of a packed pixel set as axis-parallel segments in pixel units.

    Horizontal segments are maximal runs of one kind (inside above, or inside
    below) on each grid line; vertical segments are unit pixel edges. Every
    segment ends where another begins, so the set is noded for polygonize.
    Whole-word skips and trailing-zero jumps make it O(ny·nw + segments).
    Returns ``float64 (m, 4)``: x0, y0, x1, y1.
    """
    ny, nw = bits.shape
    out = np.empty((1024, 4))
    m = 0
    for line in range(ny + 1):
        for kind in range(2):
            inrun = False
            start = 0
            for w in range(nw):
                below = bits[line - 1, w] if line > 0 else _U0
                above = bits[line, w] if line < ny else _U0
                v = (above & ~below) if kind == 0 else (below & ~above)
                if v == _U0 and not inrun:
                    continue
                if v == ALL_ONES and inrun:
                    continue
                pos = 0
                while pos < 64:
                    if inrun:
                        z = (~v) >> np.uint64(pos)
                        if z == _U0:
                            break
                        pos += trailing_zeros(z)
                        out = _push(out, m, start, line, w * 64 + pos, line)
                        m += 1
                        inrun = False
                    else:
                        o = v >> np.uint64(pos)
                        if o == _U0:
                            break
                        pos += trailing_zeros(o)
                        start = w * 64 + pos
                        inrun = True
            if inrun:
                out = _push(out, m, start, line, nw * 64, line)
                m += 1
    for i in range(ny):
        carry = _U0
        for w in range(nw):
            v = bits[i, w]
            x = v ^ ((v << _U1) | carry)
            carry = v >> np.uint64(63)
            while x != _U0:
                j = w * 64 + trailing_zeros(x)
                out = _push(out, m, j, i, j, i + 1)
                m += 1
                x &= x - _U1
        if carry != _U0:
            out = _push(out, m, nw * 64, i, nw * 64, i + 1)
            m += 1
    return out[:m]


# --------------------------------------------------------------------------- band settling
# The kernels of :mod:`printability.mmc._band` (the raster engine's band settled below the
# pixel): their mathematics and guarantees are documented there.

_INF = np.inf
_TILE = 4  # log2 of the tile side, pixels, of the bucketing's occupancy map
#: Longest chain of edges the lower bound's convex model takes (more: no model).
_MAX_CHAIN = 48


@nb.njit(cache=True, inline="always")
def _blocked(p0x, p0y, tx, ty, nx_, ny_, g0x, g0y, g1x, g1y, r):  # pragma: no cover - numba
    """The s (hull) where the line p0 + s·t comes closer than r to segment g (unit t, n)."""
    lo = _INF
    hi = -_INF
    for e in range(2):
        qx = g0x if e == 0 else g1x
        qy = g0y if e == 0 else g1y
        dx = qx - p0x
        dy = qy - p0y
        sq = dx * tx + dy * ty
        dq = dx * nx_ + dy * ny_
        w2 = r * r - dq * dq
        if w2 > 0.0:
            w = math.sqrt(w2)
            lo = min(lo, sq - w)
            hi = max(hi, sq + w)
    vx = g1x - g0x
    vy = g1y - g0y
    # hypot, not sqrt(l2): a segment ~1e-162 long has a subnormal l2 whose square root is
    # off by a percent, which would scale the normal and widen the band.  Below 1e-100 mm the
    # segment is its two endpoint disks (the sausage's middle is narrower than 1e-200 mm).
    lg = math.hypot(vx, vy)
    if lg > 1e-100:
        l2 = lg * lg
        mx = -vy / lg
        my = vx / lg
        f0 = (p0x - g0x) * mx + (p0y - g0y) * my
        ft = tx * mx + ty * my
        if ft == 0.0:
            if abs(f0) < r:
                a1, b1 = -_INF, _INF
            else:
                a1, b1 = _INF, -_INF
        else:
            a1 = (-r - f0) / ft
            b1 = (r - f0) / ft
            if a1 > b1:
                a1, b1 = b1, a1
        u0 = ((p0x - g0x) * vx + (p0y - g0y) * vy) / l2
        ut = (tx * vx + ty * vy) / l2
        if ut == 0.0:
            if 0.0 <= u0 <= 1.0:
                a2, b2 = -_INF, _INF
            else:
                a2, b2 = _INF, -_INF
        else:
            a2 = -u0 / ut
            b2 = (1.0 - u0) / ut
            if a2 > b2:
                a2, b2 = b2, a2
        a = max(a1, a2)
        b = min(b1, b2)
        if a < b:
            lo = min(lo, a)
            hi = max(hi, b)
    return lo, hi


@nb.njit(cache=True)
def _dist_point_segment(px, py, ax, ay, bx, by):  # pragma: no cover - numba
    vx = bx - ax
    vy = by - ay
    l2 = vx * vx + vy * vy
    t = 0.0
    if l2 > 0.0:
        t = ((px - ax) * vx + (py - ay) * vy) / l2
        t = min(max(t, 0.0), 1.0)
    dx = px - (ax + t * vx)
    dy = py - (ay + t * vy)
    return math.sqrt(dx * dx + dy * dy)


@nb.njit(cache=True)
def slide_intervals(me, ptr, idx, eps, eta_rel, max_free, want):  # pragma: no cover - numba
    """Free slide intervals of every mapped edge ``me`` (m, 4) against its neighbours.

    Returns (edge, s0, s1) arrays: the centres a' + (1 + eps)·n' + s·t', s0 ≤ s ≤ s1,
    whose disks of radius 1 + eps/2 meet no neighbour (module docstring). At most
    ``max_free`` intervals per edge (the longest kept; dropping some only loses
    coverage). Only the edges with ``want[e]`` slide (all still block).
    """
    m = me.shape[0]
    r = 1.0 + 0.5 * eps
    cap = m * max_free
    out_e = np.empty(cap, np.int64)
    out_0 = np.empty(cap)
    out_1 = np.empty(cap)
    most = 1
    for e in range(m):
        most = max(most, ptr[e + 1] - ptr[e])
    los = np.empty(most)
    his = np.empty(most)
    fs0 = np.empty(most + 1)
    fs1 = np.empty(most + 1)
    k = 0
    for e in range(m):
        if not want[e]:
            continue
        ax, ay, bx, by = me[e, 0], me[e, 1], me[e, 2], me[e, 3]
        dx = bx - ax
        dy = by - ay
        le = math.sqrt(dx * dx + dy * dy)
        if le <= 0.0:
            continue
        tx = dx / le
        ty = dy / le
        nx_ = -ty
        ny_ = tx
        p0x = ax + (1.0 + eps) * nx_
        p0y = ay + (1.0 + eps) * ny_
        eta = eta_rel * (abs(p0x) + abs(p0y) + le + 1.0)
        rr = r + eta
        c = 0
        for q in range(ptr[e], ptr[e + 1]):
            g = idx[q]
            g0x, g0y, g1x, g1y = me[g, 0], me[g, 1], me[g, 2], me[g, 3]
            # a segment wholly beyond r on one side of the line, or beyond either end of
            # the slide, cannot block it (the stadium's extents)
            d0 = (g0x - p0x) * nx_ + (g0y - p0y) * ny_
            d1 = (g1x - p0x) * nx_ + (g1y - p0y) * ny_
            if (d0 > rr and d1 > rr) or (d0 < -rr and d1 < -rr):
                continue
            s0_ = (g0x - p0x) * tx + (g0y - p0y) * ty
            s1_ = (g1x - p0x) * tx + (g1y - p0y) * ty
            if (s0_ < -rr and s1_ < -rr) or (s0_ > le + rr and s1_ > le + rr):
                continue
            lo, hi = _blocked(p0x, p0y, tx, ty, nx_, ny_, g0x, g0y, g1x, g1y, r)
            if lo < hi and hi > -eta and lo < le + eta:
                # insertion by lo (few blocking edges per slide)
                t = c
                while t > 0 and los[t - 1] > lo - eta:
                    los[t] = los[t - 1]
                    his[t] = his[t - 1]
                    t -= 1
                los[t] = lo - eta
                his[t] = hi + eta
                c += 1
        cur = 0.0
        nfree = 0
        for t in range(c):
            lo = los[t]
            hi = his[t]
            if lo > cur:
                fs0[nfree] = cur
                fs1[nfree] = min(lo, le)
                if fs1[nfree] > fs0[nfree]:
                    nfree += 1
            cur = max(cur, hi)
            if cur >= le:
                break
        if cur < le:
            fs0[nfree] = cur
            fs1[nfree] = le
            nfree += 1
        if nfree > max_free:
            lens = fs1[:nfree] - fs0[:nfree]
            keep = np.sort(np.argsort(-lens)[:max_free])
            for t in range(max_free):
                out_e[k] = e
                out_0[k] = fs0[keep[t]]
                out_1[k] = fs1[keep[t]]
                k += 1
            continue
        for t in range(nfree):
            out_e[k] = e
            out_0[k] = fs0[t]
            out_1[k] = fs1[t]
            k += 1
    return out_e[:k], out_0[:k], out_1[:k]


@nb.njit(cache=True)
def pivot_centres(me, prev_, ptr, idx, eps, step, want):  # pragma: no cover - numba
    """Feasible pivot centres about reflex vertices (mapped): (vertex edge, cx, cy).

    At the start vertex a' of edge e, when it is reflex (the previous edge turns
    right into e), centres a' + (1 + eps)·u at normals u strictly between the two
    edges' normals, spaced at most ``step`` radians, whose disks of radius 1 + eps/2
    meet no neighbour of either edge.
    """
    m = me.shape[0]
    r = 1.0 + 0.5 * eps
    out_e = np.empty(m * 12, np.int64)
    out_x = np.empty(m * 12)
    out_y = np.empty(m * 12)
    k = 0
    for e in range(m):
        if not want[e]:
            continue
        f = prev_[e]
        ax, ay = me[e, 0], me[e, 1]
        ex = me[e, 2] - ax
        ey = me[e, 3] - ay
        fx = me[f, 2] - me[f, 0]
        fy = me[f, 3] - me[f, 1]
        le = math.sqrt(ex * ex + ey * ey)
        lf = math.sqrt(fx * fx + fy * fy)
        if le <= 0.0 or lf <= 0.0:
            continue
        cross = fx * ey - fy * ex
        if cross >= 0.0:
            continue  # convex (left turn) or straight: no fan
        th_f = math.atan2(fx / lf, -fy / lf)  # angle of f's normal (−fy, fx)
        th_e = math.atan2(ex / le, -ey / le)
        turn = th_f - th_e  # normals turn clockwise at a right turn
        while turn <= 0.0:
            turn += 2.0 * math.pi
        while turn > 2.0 * math.pi:
            turn -= 2.0 * math.pi
        n_int = int(np.ceil(turn / step)) - 1
        if n_int > 10:
            n_int = 10
        for j in range(1, n_int + 1):
            th = th_f - turn * j / (n_int + 1)
            cx = ax + (1.0 + eps) * math.cos(th)
            cy = ay + (1.0 + eps) * math.sin(th)
            ok = True
            for src in range(2):
                ee = e if src == 0 else f
                for q in range(ptr[ee], ptr[ee + 1]):
                    g = idx[q]
                    if _dist_point_segment(cx, cy, me[g, 0], me[g, 1], me[g, 2], me[g, 3]) < r:
                        ok = False
                        break
                if not ok:
                    break
            if ok and k < out_e.shape[0]:
                out_e[k] = e
                out_x[k] = cx
                out_y[k] = cy
                k += 1
    return out_e[:k], out_x[:k], out_y[:k]


@nb.njit(cache=True)
def _bucket(quads, caps, pix_index, tiles, x0, y0, h, ny, nx, count_only, ptr, out):
    # pragma: no cover - numba
    """Pieces whose bounding box meets each uncertain pixel (CSR over ``pix_index``);
    ``tiles`` marks the 2^_TILE-pixel tiles that hold such a pixel."""
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
        for ti in range(i0 >> _TILE, (i1 >> _TILE) + 1):
            for tj in range(j0 >> _TILE, (j1 >> _TILE) + 1):
                if not tiles[ti, tj]:
                    continue  # no pixel to settle in this tile
                for i in range(max(i0, ti << _TILE), min(i1, ((ti + 1) << _TILE) - 1) + 1):
                    for j in range(max(j0, tj << _TILE), min(j1, ((tj + 1) << _TILE) - 1) + 1):
                        u = pix_index[i, j]
                        if u < 0:
                            continue
                        if count_only:
                            ptr[u + 1] += 1
                        else:
                            out[fill[u]] = p
                            fill[u] += 1


@nb.njit(cache=True)
def _edge_pixels(edges, pix_index, x0, y0, h, ny, nx, eps, count_only, ptr, out):
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


@nb.njit(cache=True, inline="always")
def _orient(ax, ay, bx, by, cx, cy):  # pragma: no cover - numba
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@nb.njit(cache=True)
def _seg_meets_box(ax, ay, bx, by, x0, y0, x1, y1):  # pragma: no cover - numba
    """Whether segment ab meets the closed box (Liang–Barsky)."""
    t0 = 0.0
    t1 = 1.0
    dx = bx - ax
    dy = by - ay
    for k in range(4):
        if k == 0:
            p, q = -dx, ax - x0
        elif k == 1:
            p, q = dx, x1 - ax
        elif k == 2:
            p, q = -dy, ay - y0
        else:
            p, q = dy, y1 - ay
        if p == 0.0:
            if q < 0.0:
                return False
        else:
            r = q / p
            if p < 0.0:
                if r > t1:
                    return False
                if r > t0:
                    t0 = r
            else:
                if r < t0:
                    return False
                if r < t1:
                    t1 = r
    return True


@nb.njit(cache=True)
def _clip_left(px, py, n, ax, ay, bx, by, ox, oy):  # pragma: no cover - numba
    """Clip the convex polygon (px, py)[:n] to the left of the line a→b; result in (ox, oy)."""
    m = 0
    for k in range(n):
        cx, cy = px[k], py[k]
        dx, dy = px[(k + 1) % n], py[(k + 1) % n]
        sc = _orient(ax, ay, bx, by, cx, cy)
        sd = _orient(ax, ay, bx, by, dx, dy)
        if sc >= 0.0:
            ox[m] = cx
            oy[m] = cy
            m += 1
        if (sc >= 0.0) != (sd >= 0.0):
            t = sc / (sc - sd)
            ox[m] = cx + t * (dx - cx)
            oy[m] = cy + t * (dy - cy)
            m += 1
    return m


@nb.njit(cache=True, inline="always")
def _area(px, py, n):  # pragma: no cover - numba
    s = 0.0
    for k in range(n):
        s += px[k] * py[(k + 1) % n] - px[(k + 1) % n] * py[k]
    return 0.5 * s


@nb.njit(cache=True)
def _in_quad(quads, q, x, y, tau, base_tol):  # pragma: no cover - numba
    """Point strictly inside quad q (≥ tau from sides 1–3; side 0, the base, down to
    −base_tol)."""
    for s in range(4):
        ax, ay = quads[q, 2 * s], quads[q, 2 * s + 1]
        bx, by = quads[q, (2 * s + 2) % 8], quads[q, (2 * s + 3) % 8]
        ln = math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)
        if ln == 0.0:
            return False
        d = _orient(ax, ay, bx, by, x, y) / ln
        if s == 0:
            if d < -base_tol:
                return False
        elif d < tau:
            return False
    return True


@nb.njit(cache=True, inline="always")
def _in_cap(caps, c, x, y):  # pragma: no cover - numba
    dx = x - caps[c, 0]
    dy = y - caps[c, 1]
    u = caps[c, 2] * dx + caps[c, 3] * dy
    v = caps[c, 4] * dx + caps[c, 5] * dy
    return u * u + v * v <= 1.0 - 1e-9


@nb.njit(cache=True)
def _disjoint_quad(quads, q, px, py, n):  # pragma: no cover - numba
    """Separating-axis test between quad q and the convex polygon (px, py)[:n]."""
    for poly in range(2):
        cnt = 4 if poly == 0 else n
        for s in range(cnt):
            if poly == 0:
                ax, ay = quads[q, 2 * s], quads[q, 2 * s + 1]
                bx, by = quads[q, (2 * s + 2) % 8], quads[q, (2 * s + 3) % 8]
            else:
                ax, ay = px[s], py[s]
                bx, by = px[(s + 1) % n], py[(s + 1) % n]
            ux = -(by - ay)
            uy = bx - ax
            amin, amax = _INF, -_INF
            for k in range(4):
                v = quads[q, 2 * k] * ux + quads[q, 2 * k + 1] * uy
                amin = min(amin, v)
                amax = max(amax, v)
            bmin, bmax = _INF, -_INF
            for k in range(n):
                v = px[k] * ux + py[k] * uy
                bmin = min(bmin, v)
                bmax = max(bmax, v)
            if amax < bmin or bmax < amin:
                return True
    return False


@nb.njit(cache=True)
def _disjoint_cap(caps, c, px, py, n):  # pragma: no cover - numba
    """Whether the convex polygon misses the ellipse (distance > 1 in its unit-disk frame)."""
    inside = True
    best = _INF
    for k in range(n):
        ax = caps[c, 2] * (px[k] - caps[c, 0]) + caps[c, 3] * (py[k] - caps[c, 1])
        ay = caps[c, 4] * (px[k] - caps[c, 0]) + caps[c, 5] * (py[k] - caps[c, 1])
        k2 = (k + 1) % n
        bx = caps[c, 2] * (px[k2] - caps[c, 0]) + caps[c, 3] * (py[k2] - caps[c, 1])
        by = caps[c, 4] * (px[k2] - caps[c, 0]) + caps[c, 5] * (py[k2] - caps[c, 1])
        if _orient(ax, ay, bx, by, 0.0, 0.0) < 0.0:
            inside = False
        best = min(best, _dist_point_segment(0.0, 0.0, ax, ay, bx, by))
    if inside:
        return False
    return best > 1.0


@nb.njit(cache=True)
def _parity_flips(edges, elist, ax, ay, bx, by):  # pragma: no cover - numba
    """Crossings of segment a→b with the listed edges; −1 when a position is degenerate."""
    flips = 0
    for t in range(elist.shape[0]):
        e = elist[t]
        px, py, qx, qy = edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3]
        o1 = _orient(ax, ay, bx, by, px, py)
        o2 = _orient(ax, ay, bx, by, qx, qy)
        o3 = _orient(px, py, qx, qy, ax, ay)
        o4 = _orient(px, py, qx, qy, bx, by)
        if o1 == 0.0 or o2 == 0.0 or o3 == 0.0 or o4 == 0.0:
            # touching or collinear: only degenerate when the boxes overlap
            if (min(px, qx) <= max(ax, bx) and min(ax, bx) <= max(px, qx)
                    and min(py, qy) <= max(ay, by) and min(ay, by) <= max(py, qy)):
                return -1
            continue
        if (o1 > 0.0) != (o2 > 0.0) and (o3 > 0.0) != (o4 > 0.0):
            flips += 1
    return flips


@nb.njit(cache=True)
def _dist_seg_box(ax, ay, bx, by, x0, y0, x1, y1):  # pragma: no cover - numba
    """Distance from segment ab to the closed box [x0, x1] × [y0, y1]."""
    if _seg_meets_box(ax, ay, bx, by, x0, y0, x1, y1):
        return 0.0
    best = _INF
    for k in range(2):
        px = ax if k == 0 else bx
        py = ay if k == 0 else by
        dx = max(x0 - px, 0.0, px - x1)
        dy = max(y0 - py, 0.0, py - y1)
        best = min(best, math.sqrt(dx * dx + dy * dy))
    for k in range(4):
        cx = x0 if k == 0 or k == 3 else x1
        cy = y0 if k < 2 else y1
        best = min(best, _dist_point_segment(cx, cy, ax, ay, bx, by))
    return best


@nb.njit(cache=True)
def _chain_of(edges, nlist, prev_, next_, x0, y0, x1, y1, reach, chain
              ):  # pragma: no cover - numba
    """The convex chain model of a box: its length n (0: none), the edges in ``chain``.

    The edges within ``reach`` of the box must be consecutive edges of one ring (or the
    whole ring), turning left at every joint (a convex chain): then G ∩ B lies in the
    intersection of their inner half-planes (:func:`settle_band`).
    """
    n = 0
    for t in range(nlist.shape[0]):
        e = nlist[t]
        if _dist_seg_box(edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3],
                         x0, y0, x1, y1) <= reach:
            if n >= chain.shape[0]:
                return 0
            chain[n] = e
            n += 1
    if n == 0:
        return 0
    # the first edge: the one whose predecessor is not in the set (none: a whole ring)
    first = -1
    for t in range(n):
        pe = prev_[chain[t]]
        found = False
        for q in range(n):
            if chain[q] == pe:
                found = True
                break
        if not found:
            if first >= 0:
                return 0  # two chains
            first = chain[t]
    closed = first < 0
    if closed:
        first = chain[0]
    # walk along the ring: every edge of the set, in order, contiguous
    e = first
    for t in range(n):
        found = False
        for q in range(t, n):
            if chain[q] == e:
                chain[q] = chain[t]
                chain[t] = e
                found = True
                break
        if not found:
            return 0
        e = next_[e]
    if closed and e != first:
        return 0
    if not closed:
        for q in range(n):
            if chain[q] == e:
                return 0  # the walk went on inside the set: not one chain
    last = n if closed else n - 1
    for t in range(last):
        e1 = chain[t]
        e2 = chain[(t + 1) % n]
        d1x = edges[e1, 2] - edges[e1, 0]
        d1y = edges[e1, 3] - edges[e1, 1]
        d2x = edges[e2, 2] - edges[e2, 0]
        d2y = edges[e2, 3] - edges[e2, 1]
        cr = d1x * d2y - d1y * d2x
        if cr < 0.0 or (cr == 0.0 and d1x * d2x + d1y * d2y <= 0.0):
            return 0  # a right turn or a spike: not convex
    return n


@nb.njit(cache=True, inline="always")
def _min_support(alpha, theta, hw, a, b):  # pragma: no cover - numba
    """min over |θ' − θ| ≤ hw of the support of R(θ')·diag(a, b)·D in direction alpha."""
    lo = alpha - theta - hw
    hi = alpha - theta + hw
    if hi - lo >= math.pi:
        c2 = 0.0
    else:
        j = math.ceil((lo - 0.5 * math.pi) / math.pi)
        if 0.5 * math.pi + j * math.pi <= hi:
            c2 = 0.0
        else:
            c2 = min(math.cos(lo) ** 2, math.cos(hi) ** 2)
    return math.sqrt(b * b + (a * a - b * b) * c2) * (1.0 - 1e-12)


@nb.njit(cache=True)
def _seg_seg_dist(ax, ay, bx, by, cx, cy, dx, dy):  # pragma: no cover - numba
    o1 = _orient(ax, ay, bx, by, cx, cy)
    o2 = _orient(ax, ay, bx, by, dx, dy)
    o3 = _orient(cx, cy, dx, dy, ax, ay)
    o4 = _orient(cx, cy, dx, dy, bx, by)
    if ((o1 > 0.0) != (o2 > 0.0)) and ((o3 > 0.0) != (o4 > 0.0)):
        return 0.0
    return min(_dist_point_segment(ax, ay, cx, cy, dx, dy),
               _dist_point_segment(bx, by, cx, cy, dx, dy),
               _dist_point_segment(cx, cy, ax, ay, bx, by),
               _dist_point_segment(dx, dy, ax, ay, bx, by))


@nb.njit(cache=True)
def _inside_convex(px, py, n, x, y):  # pragma: no cover - numba
    """Whether (x, y) lies in the closed convex polygon (px, py)[:n] (counter-clockwise)."""
    for k in range(n):
        k2 = (k + 1) % n
        if _orient(px[k], py[k], px[k2], py[k2], x, y) < 0.0:
            return False
    return True


@nb.njit(cache=True)
def _poly_dist(ax, ay, na, bx, by, nb_):  # pragma: no cover - numba
    """Distance between two convex polygons (counter-clockwise), 0 when they meet."""
    for k in range(na):
        if _inside_convex(bx, by, nb_, ax[k], ay[k]):
            return 0.0
    for k in range(nb_):
        if _inside_convex(ax, ay, na, bx[k], by[k]):
            return 0.0
    best = _INF
    for k in range(na):
        k2 = (k + 1) % na
        for q in range(nb_):
            q2 = (q + 1) % nb_
            best = min(best, _seg_seg_dist(ax[k], ay[k], ax[k2], ay[k2],
                                           bx[q], by[q], bx[q2], by[q2]))
    return best


@nb.njit(cache=True)
def _chain_lost(edges, chain, n, x0, y0, x1, y1, cells, a, b, delta, start, wx, wy, vx, vy
                ):  # pragma: no cover - numba
    """(lost, k): whether no footprint at any angle of any cell covers a point of the box
    (the convex chain model of :func:`settle_band`), and the first cell that may cover it
    (−1 when lost). Cells are tried from ``start`` on (the cell that covered a
    neighbouring leaf usually covers this one too). ``wx, wy, vx, vy`` are work arrays of
    at least ``n + 8`` entries."""
    nc = cells.shape[0]
    qx = np.empty(4)
    qy = np.empty(4)
    reach = a * (1.0 + 1e-9)
    for kk in range(nc):
        k = (start + kk) % nc
        theta, hw = cells[k, 4], cells[k, 5]
        # positions that could cover the box: within a of it; clipped to the eroded chain
        wx[0], wy[0] = x0 - reach, y0 - reach
        wx[1], wy[1] = x1 + reach, y0 - reach
        wx[2], wy[2] = x1 + reach, y1 + reach
        wx[3], wy[3] = x0 - reach, y1 + reach
        m = 4
        for t in range(n):
            e = chain[t]
            dx = edges[e, 2] - edges[e, 0]
            dy = edges[e, 3] - edges[e, 1]
            ln = math.sqrt(dx * dx + dy * dy)
            if ln == 0.0:
                continue
            nx_ = -dy / ln
            ny_ = dx / ln
            ms = _min_support(math.atan2(ny_, nx_), theta, hw, a, b)
            # the half-plane n·(t − A) ≥ ms, as "left of" the shifted edge line
            ax_ = edges[e, 0] + ms * nx_
            ay_ = edges[e, 1] + ms * ny_
            m = _clip_left(wx, wy, m, ax_, ay_, ax_ + dx, ay_ + dy, vx, vy)
            for q in range(m):
                wx[q] = vx[q]
                wy[q] = vy[q]
            if m < 3:
                break
        if m < 3 or _area(wx, wy, m) <= 0.0:
            continue  # no position at all: nothing covers the box at these angles
        m00, m01, m10, m11 = cells[k, 0], cells[k, 1], cells[k, 2], cells[k, 3]
        for c in range(4):
            px = x0 - delta if c == 0 or c == 3 else x1 + delta
            py = y0 - delta if c < 2 else y1 + delta
            qx[c] = m00 * px + m01 * py
            qy[c] = m10 * px + m11 * py
        for q in range(m):
            px, py = wx[q], wy[q]
            vx[q] = m00 * px + m01 * py
            vy[q] = m10 * px + m11 * py
        if _poly_dist(qx, qy, 4, vx, vy, m) <= 1.0 + 1e-9:
            return False, k
    return True, -1


@nb.njit(cache=True)
def _candidates(plist, quads, quad_edge, caps, elist, px0, py0, h):  # pragma: no cover
    """The pieces that meet the pixel, those on the pixel's own edges first (they are the
    ones that cover a pixel along ∂G), then caps, then the other quads."""
    nq = quads.shape[0]
    sqx = np.empty(4)
    sqy = np.empty(4)
    sqx[0], sqy[0] = px0, py0
    sqx[1], sqy[1] = px0 + h, py0
    sqx[2], sqy[2] = px0 + h, py0 + h
    sqx[3], sqy[3] = px0, py0 + h
    out = np.empty(plist.shape[0], np.int64)
    rank = np.empty(plist.shape[0], np.int64)
    m = 0
    for t in range(plist.shape[0]):
        p = plist[t]
        if p < nq:
            if _disjoint_quad(quads, p, sqx, sqy, 4):
                continue
            own = False
            for k in range(elist.shape[0]):
                if quad_edge[p] == elist[k]:
                    own = True
                    break
            rank[m] = 0 if own else 2
        else:
            if _disjoint_cap(caps, p - nq, sqx, sqy, 4):
                continue
            rank[m] = 1
        out[m] = p
        m += 1
    order = np.argsort(rank[:m], kind="mergesort")
    return out[:m][order]


@nb.njit(cache=True)
def _settle_pixels(pix_i, pix_j, cls, cov, outer, x0, y0, h, edges, prev_, next_, eptr,
                   eidx, nptr, nidx, quads, quad_edge, caps, pptr, pidx, cells, a, b, delta,
                   reach, max_level, tau):  # pragma: no cover - numba
    """Per uncertain pixel: certified upper and lower bounds of λ(p ∩ G \\ S) and the area
    left undecided (module docstring), mm²."""
    n = pix_i.shape[0]
    upper = np.empty(n)
    lower = np.empty(n)
    undecided = np.empty(n)
    estimate = np.empty(n)
    reopen = np.zeros(n)
    nq = quads.shape[0]
    sx = np.empty(4 * (max_level + 2) + 8)
    sy = np.empty_like(sx)
    sz = np.empty_like(sx)
    sl = np.empty(sx.shape[0], np.int64)
    px = np.empty(8)
    py = np.empty(8)
    rx = np.empty(8)
    ry = np.empty(8)
    most = 1
    for u in range(n):
        most = max(most, pptr[u + 1] - pptr[u])
    # candidates per level: a leaf's children only test the pieces that touch the leaf
    cbuf = np.empty((max_level + 2, most), np.int64)
    clen = np.zeros(max_level + 2, np.int64)
    chain = np.empty(_MAX_CHAIN, np.int64)
    wx = np.empty(_MAX_CHAIN + 8)
    wy = np.empty_like(wx)
    vx = np.empty_like(wx)
    vy = np.empty_like(wx)
    for u in range(n):
        i = pix_i[u]
        j = pix_j[u]
        c = cls[i, j]
        cap_area = cov[i, j] * h * h
        if not outer[i, j]:
            # the raster's outer pass proves no footprint reaches it: all of it is lost
            upper[u] = cap_area
            lower[u] = cap_area
            undecided[u] = 0.0
            estimate[u] = cap_area
            continue
        elist = eidx[eptr[u]:eptr[u + 1]]
        nlist = nidx[nptr[u]:nptr[u + 1]]
        plist = _candidates(pidx[pptr[u]:pptr[u + 1]], quads, quad_edge, caps, elist,
                            x0 + j * h, y0 + i * h, h)
        cbuf[0, :plist.shape[0]] = plist
        clen[0] = plist.shape[0]
        cxp = x0 + (j + 0.5) * h
        cyp = y0 + (i + 0.5) * h
        centre_in = c >= 2
        # a centre on ∂G has no trustworthy parity: every leaf without an edge counts as inside
        centre_ok = True
        for t in range(elist.shape[0]):
            e = elist[t]
            if _dist_point_segment(cxp, cyp, edges[e, 0], edges[e, 1], edges[e, 2],
                                   edges[e, 3]) <= tau:
                centre_ok = False
        up = 0.0
        low = 0.0
        und = 0.0
        est = 0.0
        hint = 0
        sx[0] = x0 + j * h
        sy[0] = y0 + i * h
        sz[0] = h
        sl[0] = 0
        top = 1
        while top > 0:
            top -= 1
            lx, ly, ls, lev = sx[top], sy[top], sz[top], sl[top]
            cand = cbuf[lev, :clen[lev]]
            g = tau
            ne = 0
            one = -1
            two = -1
            for t in range(elist.shape[0]):
                e = elist[t]
                if _seg_meets_box(edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3],
                                  lx - g, ly - g, lx + ls + g, ly + ls + g):
                    ne += 1
                    if ne == 1:
                        one = e
                    elif ne == 2:
                        two = e
                    else:
                        break
            px[0], py[0] = lx, ly
            px[1], py[1] = lx + ls, ly
            px[2], py[2] = lx + ls, ly + ls
            px[3], py[3] = lx, ly + ls
            npts = 4
            base_ok = False
            exact_area = True  # whether ``area`` is λ(leaf ∩ G) (else only ≥ it)
            if ne == 0:
                inside = True
                if c == 3:
                    inside = True
                elif centre_ok:
                    fl = -1
                    for attempt in range(3):
                        fx = 0.5 if attempt == 0 else (0.3141 if attempt == 1 else 0.7183)
                        fy = 0.5 if attempt == 0 else (0.6931 if attempt == 1 else 0.2718)
                        qx = lx + fx * ls
                        qy = ly + fy * ls
                        fl = _parity_flips(edges, elist, cxp, cyp, qx, qy)
                        if fl >= 0:
                            break
                    if fl >= 0:
                        inside = centre_in != (fl % 2 == 1)
                    else:
                        exact_area = False
                else:
                    exact_area = False
                if not inside:
                    continue
                area = ls * ls
            elif ne == 1 or (ne == 2 and (prev_[one] == two or prev_[two] == one)
                             and _convex_pair(edges, prev_, one, two)):
                m = _clip_left(px, py, 4, edges[one, 0], edges[one, 1], edges[one, 2],
                               edges[one, 3], rx, ry)
                if ne == 2 and m >= 3:
                    for k in range(m):
                        px[k] = rx[k]
                        py[k] = ry[k]
                    m = _clip_left(px, py, m, edges[two, 0], edges[two, 1], edges[two, 2],
                                   edges[two, 3], rx, ry)
                if m < 3:
                    continue
                for k in range(m):
                    px[k] = rx[k]
                    py[k] = ry[k]
                npts = m
                area = _area(px, py, npts)
                if area <= 0.0:
                    continue
                base_ok = ne == 1
            else:
                area = ls * ls
                if lev >= max_level:
                    up += area
                    und += area
                    est += 0.5 * area
                    continue
                cbuf[lev + 1, :cand.shape[0]] = cand
                clen[lev + 1] = cand.shape[0]
                for dy in range(2):
                    for dx in range(2):
                        sx[top] = lx + dx * 0.5 * ls
                        sy[top] = ly + dy * 0.5 * ls
                        sz[top] = 0.5 * ls
                        sl[top] = lev + 1
                        top += 1
                continue
            covered = False
            for t in range(cand.shape[0]):
                p = cand[t]
                ok = True
                for k in range(npts):
                    if p < nq:
                        if not _in_quad(quads, p, px[k], py[k], tau,
                                        tau if base_ok else -tau):
                            ok = False
                            break
                    elif not _in_cap(caps, p - nq, px[k], py[k]):
                        ok = False
                        break
                if ok:
                    covered = True
                    break
            if covered:
                continue
            nch = _chain_of(edges, nlist, prev_, next_, lx, ly, lx + ls, ly + ls, reach,
                            chain)
            if nch > 0 and exact_area:
                lost, k = _chain_lost(edges, chain, nch, lx, ly, lx + ls, ly + ls, cells, a,
                                      b, delta, hint, wx, wy, vx, vy)
                if lost:
                    up += area
                    low += area
                    est += area
                    continue
                hint = k
            nt = 0
            for t in range(cand.shape[0]):
                p = cand[t]
                if p < nq:
                    if not _disjoint_quad(quads, p, px, py, npts):
                        cbuf[lev + 1, nt] = p
                        nt += 1
                elif not _disjoint_cap(caps, p - nq, px, py, npts):
                    cbuf[lev + 1, nt] = p
                    nt += 1
            clen[lev + 1] = nt
            touching = nt > 0
            if not touching and nch == 0:
                up += area
                est += area
                reopen[u] += area
                continue
            if lev >= max_level:
                up += area
                und += area
                # no piece of any sampled angle reaches it: the estimate counts it lost
                est += 0.5 * area if touching else area
                reopen[u] += area
                continue
            for dy in range(2):
                for dx in range(2):
                    sx[top] = lx + dx * 0.5 * ls
                    sy[top] = ly + dy * 0.5 * ls
                    sz[top] = 0.5 * ls
                    sl[top] = lev + 1
                    top += 1
        upper[u] = min(up, cap_area)
        lower[u] = min(low, upper[u])
        undecided[u] = min(und, upper[u] - lower[u])
        estimate[u] = min(max(est, lower[u]), upper[u])
    return upper, lower, undecided, estimate, reopen


@nb.njit(cache=True, inline="always")
def _convex_pair(edges, prev_, e1, e2):  # pragma: no cover - numba
    """Whether the adjacent edges e1, e2 meet at a convex vertex (a left turn)."""
    if prev_[e1] == e2:
        e_in, e_out = e2, e1
    else:
        e_in, e_out = e1, e2
    dix = edges[e_in, 2] - edges[e_in, 0]
    diy = edges[e_in, 3] - edges[e_in, 1]
    dox = edges[e_out, 2] - edges[e_out, 0]
    doy = edges[e_out, 3] - edges[e_out, 1]
    return dix * doy - diy * dox > 0.0

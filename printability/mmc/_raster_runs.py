"""Run-length kernels of the raster MMC engine: runs, their labels, a mask's boundary.

Masks are bit-packed as in :mod:`printability.mmc._raster_kernels` (64 pixels per
``uint64`` word, least significant bit first). Whole words of 0s or 1s are skipped and the
next transition inside a mixed word is found with a trailing-zero count, so each kernel
costs O(ny·nw + output) rather than O(ny·nx).
"""

from __future__ import annotations

import numba as nb
import numpy as np
from numba.cpython.unsafe.numbers import trailing_zeros

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.mmc._raster_kernels import ALL_ONES

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["boundary_segments", "extract_runs", "label_runs", "overlap_pairs"]

_U0 = np.uint64(0)
_U1 = np.uint64(1)


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

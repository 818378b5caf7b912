"""The bit-parallel opening passes of the raster MMC engine (:mod:`printability.mmc.raster`).

A pass computes ∪_k (X ⊖ E_k) ⊕ D_k, ∩ a target, on bit-packed rows with the
word kernels of :mod:`printability.mmc._raster_kernels` (erosion and
dilation as defined in :mod:`printability.mmc.raster`); the kernels are
given as horizontal runs.

Speed
    Masks are bit-packed, 64 pixels per ``uint64`` word. A footprint is a
    union of horizontal runs; eroding a word is the AND over runs of two
    reads of a doubling table (AND of 2^l consecutive pixels), so its cost is
    about 2 × rows of the kernel per 64 pixels, whatever the run lengths. Only
    the words in the band where P can change with the angle are computed
    (the pixels P holds at every angle, X ⊖ ∪_k K(k), are computed once, and
    P is empty outside X ⊖ ∩_k K(k)); a word stops at 0. The dilation only
    visits words with target pixels not yet in the union, stops once they
    are covered, and its target drops pixels no angle can reach: those not
    in (X ⊖ ∩_k K(k)) ⊕ ∪_k K_dil(k), and for the inner pass the pixels next
    to a non-inside pixel (a pixel wholly inside a closed footprint makes it
    touch the 8 neighbours, which must then be inside: S_in ⊆ I ⊖ 3×3). The
    outer and estimate passes store no P, so they erode only the band words
    a dilation can still read (near words with uncovered target pixels).
    All of it is exact: the benchmark checks every pixel against OpenCV.
    Cost per angle O(band words × kernel rows); memory ≈ 24 bytes per pixel
    plus 8 bytes per band word and angle.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from printability.mmc._raster_kernels import (
    ALL_ONES,
    build_tables,
    dilate_words,
    erode_words,
    flat_runs,
    near_needy,
    table_padding,
    update_tables,
)

__all__ = ["PassResult", "_mask_runs", "opening_pass"]


@dataclass(frozen=True)
class _Runs:
    """A kernel as horizontal runs for the word kernels: rows (dy, a, level, second)."""

    table: np.ndarray

    @property
    def max_level(self) -> int:
        return int(self.table[:, 2].max()) if len(self.table) else 0


def _mask_runs(mask: np.ndarray, radius: int) -> list[tuple[int, int, int]]:
    """(di, dj_start, length) of the True runs of a kernel mask."""
    padded = np.zeros((mask.shape[0], mask.shape[1] + 2), np.int8)
    padded[:, 1:-1] = mask
    rows, cols = np.nonzero(np.diff(padded, axis=1))
    starts, stops = cols[::2], cols[1::2]
    return list(zip((rows[::2] - radius).tolist(), (starts - radius).tolist(),
                    (stops - starts).tolist(), strict=True))


def _to_runs(runs: list[tuple[int, int, int]], *, dilate: bool, order_from_centre: bool
             ) -> _Runs:
    """Word-kernel runs; a dilation run reads row i − di from column j − dj − L + 1."""
    # Runs longer than 64 pixels are split: a doubling-table level l combines word w with
    # word w + 1 shifted by 2^(l-1) bits, which is only defined up to level 6 (32-bit
    # shift; a 64-bit shift of a uint64 is undefined). Unsplit 128+ pixel runs (a 1 mm
    # nozzle at h < 0.008 mm) made erosion keep infeasible positions.
    split = []
    for di, dj, L in runs:
        for s0 in range(0, L, 64):
            split.append((di, dj + s0, min(64, L - s0)))
    runs = split
    if dilate:
        # the dilation kernel reads row i − di from column j − dj − L + 1
        runs = [(-di, -dj - L + 1, L) for di, dj, L in runs]
    if runs:
        # erosion stops at 0: the runs far from the centre decide first; dilation stops when
        # covered: the central runs first.
        key = [abs(di) + abs(dj + L / 2) for di, dj, L in runs]
        order = np.argsort(key)
        if not order_from_centre:
            order = order[::-1]
        runs = [runs[t] for t in order]
    dy = np.array([r[0] for r in runs], np.int64)
    a = np.array([r[1] for r in runs], np.int64)
    L = np.array([r[2] for r in runs], np.int64)
    lev = np.floor(np.log2(np.maximum(L, 1))).astype(np.int64)
    m = np.left_shift(1, lev)
    second = np.where(L > m, L - m, -1).astype(np.int64)
    return _Runs(np.ascontiguousarray(np.column_stack([dy, a, lev, second]).reshape(-1, 4)))



@dataclass
class PassResult:
    """What an opening pass leaves: its union and, per angle, P on the band's words."""

    union: np.ndarray        # packed S of the pass
    base: np.ndarray         # packed deep P (held at every angle)
    band_i: np.ndarray
    band_w: np.ndarray
    values: np.ndarray       # (n, nband) when stored, else (0, nband)


def _last_mask(nx: int) -> np.uint64:
    r = nx % 64
    return ALL_ONES if r == 0 else np.uint64((1 << r) - 1)


def opening_pass(inp: np.ndarray, target: np.ndarray, erode_k: np.ndarray, dilate_k: np.ndarray,
                 radius: int, nx: int, *, store: bool, tick: Callable[[], None],
                 check: Callable[[int], None] | None = None) -> PassResult:
    """∪_k (inp ⊖ erode_k[k]) ⊕ dilate_k[k], ∩ target, on packed rows (see module docstring).

    ``check(band_words)`` is called before the per-angle words are allocated.
    """
    ny, nw = inp.shape
    last = _last_mask(nx)
    n = erode_k.shape[0]
    er = [_to_runs(_mask_runs(m, radius), dilate=False, order_from_centre=False) for m in erode_k]
    di = [_to_runs(_mask_runs(m, radius), dilate=True, order_from_centre=True) for m in dilate_k]
    union_runs = _to_runs(_mask_runs(erode_k.any(axis=0), radius), dilate=False,
                          order_from_centre=False)
    common_runs = _to_runs(_mask_runs(erode_k.all(axis=0), radius), dilate=False,
                           order_from_centre=False)
    reach_runs = _to_runs(_mask_runs(dilate_k.any(axis=0), radius), dilate=True,
                          order_from_centre=True)
    pr, pw = table_padding(radius)
    lev_e = 1 + max([r.max_level for r in er] + [union_runs.max_level])
    t_and = np.zeros((lev_e, ny + 2 * pr, nw + 2 * pw), np.uint64)
    build_tables(inp, t_and, pr, pw, True, 0, ny)
    fa = t_and.reshape(-1)
    nwp = t_and.shape[2]

    def flat(r: _Runs, table: np.ndarray) -> np.ndarray:
        return flat_runs(r.table, table.shape, pr, pw)

    all_i = np.repeat(np.arange(ny, dtype=np.int64), nw)
    all_w = np.tile(np.arange(nw, dtype=np.int64), ny)
    empty = np.zeros(0, np.uint64)
    # deep: held at every angle (erosion by the union of the kernels); maybe: may be held at
    # some angle (erosion by their intersection); only the words between are computed per angle
    deep = np.empty((ny, nw), np.uint64)
    erode_words(fa, nwp, flat(union_runs, t_and), all_i, all_w, last, deep, empty)
    maybe = np.empty((ny, nw), np.uint64)
    erode_words(fa, nwp, flat(common_runs, t_and), all_i, all_w, last, maybe, empty)
    del all_i, all_w
    # pixels no angle can reach are dropped from the dilation target, so that words whose
    # remaining pixels are out of reach are not recomputed at every angle
    lev_d = 1 + max([r.max_level for r in di] + [reach_runs.max_level])
    t_or = np.zeros((lev_d, ny + 2 * pr, nw + 2 * pw), np.uint64)
    build_tables(maybe, t_or, pr, pw, False, 0, ny)
    reach = np.zeros((ny, nw), np.uint64)
    fo = t_or.reshape(-1)
    dilate_words(fo, nwp, flat(reach_runs, t_or), target, reach)
    band = np.flatnonzero((maybe & ~deep).reshape(-1))
    del maybe
    band_i = (band // nw).astype(np.int64)
    band_w = (band % nw).astype(np.int64)
    if check is not None:
        check(len(band))
    values = np.empty((n if store else 0, len(band)), np.uint64)
    work = deep.copy()
    build_tables(work, t_or, pr, pw, False, 0, ny)
    union = np.zeros((ny, nw), np.uint64)
    # a dilation of output word (i, w) reads P rows i ± radius and words w ± rw
    rw = radius // 64 + 3
    for k in range(n):
        if store:
            sel_i, sel_w = band_i, band_w
            erode_words(fa, nwp, flat(er[k], t_and), sel_i, sel_w, last, work, values[k])
        else:
            # only P words a dilation can still read need to be right: those near words
            # with target pixels not yet covered (stale words elsewhere are never read)
            sel = near_needy(reach, union, band_i, band_w, radius, rw)
            sel_i, sel_w = band_i[sel], band_w[sel]
            erode_words(fa, nwp, flat(er[k], t_and), sel_i, sel_w, last, work, empty)
        if len(di[k].table):
            update_tables(work, t_or, pr, pw, sel_i, sel_w, False)
            dilate_words(fo, nwp, flat(di[k], t_or), reach, union)
        tick()
    return PassResult(union, deep, band_i, band_w, values)


"""Compiled helpers of the split search (printability.planning._search.split_many)
against the numpy code they replaced: the same intervals, in the same order, to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from printability.planning._plan_kernels import points_along, split_intervals


def _intervals_numpy(length, step, ncol):
    """The candidate intervals as split_many generated them with numpy."""
    mv_l, t0_l, t1_l, rank_l = [], [], [], []
    live = np.flatnonzero(length > 2 * step)
    d = step / length[live]
    level = 0
    while live.size:
        more = d < 0.5
        live, d = live[more], d[more]
        for kind, (t0, t1) in enumerate(((d, np.ones_like(d)), (np.zeros_like(d), 1.0 - d),
                                         (d, 1.0 - d))):
            mv_l.append(live)
            t0_l.append(t0)
            t1_l.append(t1)
            rank_l.append(np.full(live.size, level * 3 + kind))
        d = d * 2.0
        level += 1
    mv = np.concatenate(mv_l) if mv_l else np.zeros(0, dtype=np.int64)
    t0a = np.concatenate(t0_l) if t0_l else np.zeros(0)
    t1a = np.concatenate(t1_l) if t1_l else np.zeros(0)
    rank = np.concatenate(rank_l) if rank_l else np.zeros(0, dtype=np.int64)
    span = t1a - t0a
    cand_iv = np.repeat(np.arange(mv.size), ncol)
    cand_col = np.tile(np.arange(ncol), mv.size)
    srt = np.lexsort((rank[cand_iv] * ncol + cand_col, -span[cand_iv], mv[cand_iv]))
    cand_iv, cand_col = cand_iv[srt], cand_col[srt]
    moves, gpos, cnt = np.unique(mv[cand_iv], return_index=True, return_counts=True)
    return mv[cand_iv], t0a[cand_iv], t1a[cand_iv], cand_col, moves, gpos, gpos + cnt


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("ncol", [1, 2])
def test_split_intervals_are_the_numpy_ones(seed, ncol):
    rng = np.random.default_rng(seed)
    step = 0.1
    # short moves (no interval), lengths at the thresholds, long ones (many levels)
    length = np.concatenate([rng.uniform(0, 0.5, 300), rng.uniform(0, 30, 300),
                             [0.2, 0.2 + 1e-12, 0.4, 0.8, 1.6, 0.0, 1e-9, 100.0]])
    rng.shuffle(length)
    ref = _intervals_numpy(length, step, ncol)
    iv_mv, iv_t0, iv_t1, moves, ivpos = split_intervals(length, step)
    niv = iv_mv.size
    cand_iv = np.repeat(np.arange(niv), ncol)
    got = (iv_mv[cand_iv], iv_t0[cand_iv], iv_t1[cand_iv], np.tile(np.arange(ncol), niv),
           moves, ivpos[:-1] * ncol, ivpos[1:] * ncol)
    for a, b in zip(got, ref, strict=True):
        assert a.tobytes() == b.astype(a.dtype).tobytes()
    assert np.all(np.diff(ivpos) > 0) and moves.size > 300


@pytest.mark.parametrize("seed", [0, 1])
def test_points_along_are_the_numpy_ones(seed):
    """The compiled points along the moves are numpy's ``a[idx] + t[:, None] * ba[idx]`` to
    the bit (the planner's footprints, hence its decisions, depend on them)."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(-300, 300, (500, 2))
    ba = rng.normal(0, 5, (500, 2))
    ba[:5] = 0.0
    idx = rng.integers(0, 500, 4000)
    t = np.concatenate([[0.0, 1.0, 0.5], rng.uniform(0, 1, 3997)])
    np.testing.assert_array_equal(points_along(a, ba, idx, t), a[idx] + t[:, None] * ba[idx])
    assert points_along(a, ba, idx[:0], t[:0]).shape == (0, 2)

"""The orientation planner turns on rather than rocking (issue 22).

:func:`printability.motion.orientation._least_turning` re-picks every whole move's
orientation among admissible candidates with a Viterbi pass over each path
(:func:`printability.motion._plan_kernels.chain_viterbi`): a turn the nozzle must make
standing still (a full stop of the XY motion on real firmware) and a reversal cost extra.
On real slicer files it must turn less, stand still less and reverse less than the
move-by-move picks it replaces, and keep every pick admissible (the deposition checks of
``test_postprocess`` hold the MMC promise on the same files).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

import printability.motion.orientation as orientation
from printability.motion._plan_kernels import chain_viterbi
from printability.postprocess import PostprocessOptions, postprocess_bytes

_C = re.compile(rb"(?<![A-Z;])C(-?[0-9.]+)")
_XYZE = re.compile(rb"[XYZE]-?[0-9.]")


def _turns(data: bytes) -> tuple[int, float, int]:
    """Rotation-only lines, total |ΔC| and reversals of the C words of a file."""
    c_prev = None
    standing = 0
    steps = []
    for line in data.splitlines():
        code = line.split(b";", 1)[0]
        m = _C.search(code)
        if not m or not code.startswith((b"G0", b"G1")):
            continue
        c = float(m.group(1))
        if not _XYZE.search(code):
            standing += 1
        if c_prev is not None and abs(c - c_prev) > 1e-9:
            steps.append(c - c_prev)
        c_prev = c
    s = np.sign(steps)
    return standing, float(np.abs(steps).sum()), int(np.sum(s[1:] != s[:-1]))


@pytest.mark.parametrize("fixture", ["prusa_short", "benchy_short"])
def test_the_axis_turns_on_rather_than_rocking(request, monkeypatch, fixture):
    data = request.getfixturevalue(fixture).read_bytes()
    options = PostprocessOptions(nozzle="ellipse:major=0.8,minor=0.3", machine="ttr")
    new, res = postprocess_bytes(data, options=options)
    with monkeypatch.context() as m:
        m.setattr(orientation, "_least_turning", lambda angle, *a, **kw: angle)
        old, res_old = postprocess_bytes(data, options=options)
    standing, total, reversals = _turns(new)
    standing_old, total_old, reversals_old = _turns(old)
    assert standing < 0.8 * standing_old
    assert total < 0.9 * total_old
    assert reversals < 0.8 * reversals_old
    # whole moves only change: what is split or dropped stays as it was
    assert sum(r.dropped_length for r in res.layers) == \
        pytest.approx(sum(r.dropped_length for r in res_old.layers), rel=1e-9, abs=1e-9)


def _viterbi(cand, chained, folds=None, cost=None, stop=60.0, reverse=20.0):
    cand = np.asarray(cand, float)
    n, k = cand.shape
    f = np.zeros((n, k, k), np.uint8)
    f[np.asarray(chained, bool)] = 1
    if folds is not None:
        for i, j, c in folds:
            f[i, j, c] = 2
    cost = np.zeros((n, k)) if cost is None else np.asarray(cost, float)
    return chain_viterbi(cand, cand.copy(), cost, f, np.array([180.0, stop, 0.25, reverse]))


def test_viterbi_keeps_one_side_rather_than_alternating():
    # ±θ of a straight line: the move-by-move chain may hop between them; one side holds
    cand = [[23.35, -23.35]] * 5
    pick = _viterbi(cand, [False] + [True] * 4)
    assert len(set(pick.tolist())) == 1


def test_viterbi_prefers_a_larger_turn_made_during_the_move_to_a_standstill():
    # 0 → (15 standing still, or 19 during the move) → 19
    cand = [[0.0, np.nan], [15.0, 19.0], [19.0, np.nan]]
    pick = _viterbi(cand, [False, True, True], folds=[(1, 0, 1)])
    assert pick.tolist() == [0, 1, 0]


def test_viterbi_counts_reversals_and_breaks_at_dropped_moves():
    # up 10 then either back down 10 (a reversal) or on up 12
    cand = [[0.0, np.nan], [10.0, np.nan], [0.0, 22.0]]
    assert _viterbi(cand, [False, True, True]).tolist() == [0, 0, 1]
    assert _viterbi(cand, [False, True, True], reverse=0.0).tolist() == [0, 0, 0]
    # a move without candidates: the path starts again after it
    cand = [[0.0, np.nan], [np.nan, np.nan], [90.0, 0.0]]
    assert _viterbi(cand, [False, True, True]).tolist() == [0, -1, 0]

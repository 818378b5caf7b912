"""The compiled width picks of preferred_orientations against the numpy rows they replaced."""

from __future__ import annotations

import numpy as np
import pytest

from printability.motion._plan_kernels import width_picks
from printability.motion.orientation import _half_turn_distance, width_table
from printability.nozzle import parse_nozzle


def _picks_numpy(w, wtab, beta):
    err = np.abs(wtab[None, :] - w[:, None])
    j1 = np.argmin(err, axis=1)
    e1 = err[np.arange(len(j1)), j1]
    dist = _half_turn_distance(beta)[j1]
    err2 = np.where(dist > 2.0, err, np.inf)
    j2 = np.argmin(err2, axis=1)
    e2 = err2[np.arange(len(j2)), j2]
    return beta[j1], np.where(e2 <= e1 + 1e-4, beta[j2], beta[j1])


@pytest.mark.parametrize("nozzle", ["ellipse:major=0.8,minor=0.3", "rect:w=0.7,h=0.25",
                                    "circle:d=0.4"])
def test_width_picks_are_the_numpy_rows(nozzle):
    beta_all, wtab_all = width_table(parse_nozzle(nozzle))
    half = beta_all < 180.0
    beta, wtab = beta_all[half], wtab_all[half]
    rng = np.random.default_rng(7)
    # widths inside, outside and exactly at the table's values (ties: the first minimum)
    w = np.unique(np.concatenate([rng.uniform(0.0, 1.2, 500), wtab[::7],
                                  (wtab[:-1] + wtab[1:]) / 2, [0.0, wtab.min(), wtab.max()]]))
    got = width_picks(w, np.ascontiguousarray(wtab), np.ascontiguousarray(beta),
                      _half_turn_distance(beta))
    ref = _picks_numpy(w, wtab, beta)
    for a, b in zip(got, ref, strict=True):
        assert a.tobytes() == b.tobytes()

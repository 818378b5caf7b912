"""printability.base.arrays.take_rows is plain indexing, faster (the values are the same)."""

from __future__ import annotations

import numpy as np

from gcode import parse_gcode
from printability.base.arrays import take_rows


def test_take_rows_is_indexing_on_rows_and_records(shared_data):
    g = parse_gcode((shared_data / "gcode" / "prusaslicer_2.7.4_marlin2_arcs.gcode").read_bytes())
    idx = np.flatnonzero(g.moves["e"] > 0)[::3]
    assert take_rows(g.moves, idx).tobytes() == g.moves[idx].tobytes()
    pts = np.random.default_rng(0).uniform(-5, 5, (500, 2))
    rows = np.array([4, 0, 499, 4, 17])
    assert np.array_equal(take_rows(pts, rows), pts[rows])
    assert take_rows(pts, np.zeros(0, np.int64)).shape == (0, 2)

"""One width rule for the layer targets and the post-processor."""

from __future__ import annotations

import numpy as np
import pytest

from gcode import NON_PART_CATEGORIES, parse_gcode
from printability.sources.gcode import segment_widths


@pytest.mark.parametrize("name", ["cura_5.9.1_marlin.gcode", "slic3rpe_1.33_arcwelder_benchy.gcode",
                                  "prusaslicer_2.7.4_marlin2_arcs.gcode"])
def test_zero_length_chords_change_no_width(shared_data, name):
    g = parse_gcode((shared_data / "gcode" / name).read_bytes())
    m = g.moves
    cats = g.feature_category_of_moves()
    part = np.array([c not in NON_PART_CATEGORIES for c in cats])
    idx = np.flatnonzero(m["is_extrusion"] & part & ~m["wipe"] & (m["layer"] >= 0))
    seg = g.segments(moves=m[idx])
    mv = idx[seg["move"]]
    w_all, derived, _ = segment_widths(g, seg, mv, filament_diameter=1.75, model="auto")
    ok = np.hypot(seg["x1"] - seg["x0"], seg["y1"] - seg["y0"]) > 0
    w_ok, _, _ = segment_widths(g, seg[ok], mv[ok], filament_diameter=1.75, model="auto")
    np.testing.assert_array_equal(w_all[ok], w_ok)
    # comment widths are kept where given (up to the outlier cap)
    if not derived.all():
        given = m["width"][mv][~derived]
        assert np.nanmedian(w_all[~derived]) == pytest.approx(np.nanmedian(given))


def test_ignoring_comments_derives_every_width(shared_data):
    g = parse_gcode((shared_data / "gcode" / "prusaslicer_2.7.4_marlin2_arcs.gcode").read_bytes())
    idx = np.flatnonzero(g.moves["is_extrusion"] & (g.moves["layer"] >= 0))[:2000]
    seg = g.segments(moves=g.moves[idx])
    mv = idx[seg["move"]]
    w, derived, clipped = segment_widths(g, seg, mv, filament_diameter=1.75, model="stadium",
                                         use_width_comments=False)
    assert derived.all()
    good = np.isfinite(w)
    assert good.mean() > 0.95 and 0.2 < np.median(w[good]) < 1.0
    assert (w[good] <= 3.0 * np.median(w[good & ~clipped]) + 1e-9).all()

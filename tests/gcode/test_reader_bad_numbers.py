"""Moves whose numbers no firmware reads the same way are refused with the line named; no
non-finite or absurd coordinate ever reaches the move table."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gcode import parse_gcode
from printability.errors import FileFormatError

HEAD = b"G28\nG90\nM83\nG1 Z0.2 F600\nG1 X10 Y10 F1200\n"


@pytest.mark.parametrize(("word", "match"), [
    ("Xnan", "X without a number"),
    ("Xinf", "X without a number"),
    ("X", "X without a number"),
    ("X1e309", "exponent notation"),
    ("X1e3", "exponent notation"),
    ("X2000000", "X out of range"),
    ("E-9999999", "E out of range"),
    ("F1e8", "exponent notation"),
    ("F20000000", "F out of range"),
    ("X" + "9" * 400, "X out of range"),
])
def test_refused_with_the_line_named(word, match):
    data = HEAD + f"G1 {word} Y71.838 E.38291\n".encode()
    with pytest.raises(FileFormatError, match=match) as exc:
        parse_gcode(data, path="part.gcode")
    assert "part.gcode, line 6" in str(exc.value)
    assert len(str(exc.value)) < 400  # a short excerpt, not the line


@pytest.mark.parametrize("line", ["G1 X10E.5", "G1X10Y20E.1F1800", "G1 X-0.5 Y+.25 E1",
                                  "G92 E0", "M84 X Y E", "G28 X Y"])
def test_plain_gcode_still_reads(line):
    g = parse_gcode(HEAD + line.encode() + b"\n")
    assert np.isfinite(g.moves["x1"][-1])


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet="XYZEF0123456789.-+eEnaif ", min_size=1, max_size=24))
def test_no_non_finite_coordinate_survives(words):
    data = HEAD + b"G1 " + words.encode() + b"\n"
    try:
        g = parse_gcode(data)
    except FileFormatError:
        return
    m = g.moves
    for k in ("x1", "y1", "z1", "e", "feed"):
        v = m[k][np.isfinite(m[k])]
        assert (np.abs(v) <= 1e7).all()
    assert not np.isinf(m[["x1", "y1", "z1"]].tolist()).any()

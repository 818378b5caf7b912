"""The rotary-axis G-code writer: unwrapping, words, feed policies, E, line edits, golden file."""

from __future__ import annotations

import itertools
import math
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gcode import parse_gcode
from gcode.rotary import (
    arc_points,
    bead_area,
    e_per_mm,
    feed_for_move,
    nearest_equivalent,
    unwrap_sequence,
    width_from_e,
)
from gcode.writer import (
    Emitter,
    WriterOptions,
    edit_e,
    edit_line,
    format_number,
    header_lines,
)

GOLDEN = Path(__file__).with_name("golden")


@pytest.mark.parametrize(("value", "decimals", "text"), [
    (1.0, 3, "1"), (-0.0001, 3, "0"), (0.1256, 3, "0.126"), (-12.5, 2, "-12.5"),
    (1800.4, 0, "1800"),
])
def test_format_number(value, decimals, text):
    assert format_number(value, decimals) == text


@given(st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6),
       st.integers(0, 8))
def test_format_number_rounds_as_python_formats(value, decimals):
    """The digits of f"{value:.{decimals}f}" (correctly rounded), trailing zeros dropped."""
    ref = f"{value:.{decimals}f}"
    if "." in ref:
        ref = ref.rstrip("0").rstrip(".")
    assert format_number(value, decimals) == ("0" if ref in ("-0", "") else ref)


@pytest.mark.parametrize(("target", "prev", "period", "expected"), [
    (350.0, 0.0, 360.0, -10.0),      # shortest signed step, not +350
    (170.0, 0.0, 180.0, -10.0),      # an ellipse turns 10°, not 170°
    (10.0, 725.0, 360.0, 730.0),     # unwrapped: stays near the current coordinate
    (95.0, 0.0, 180.0, -85.0),
])
def test_nearest_equivalent(target, prev, period, expected):
    assert nearest_equivalent(target, prev, period=period) == pytest.approx(expected)


def test_nearest_equivalent_limits():
    # limited axis: the representative must be inside [lo, hi] even if it turns more
    assert nearest_equivalent(100.0, 80.0, period=360.0, lo=-90, hi=90) is None
    assert nearest_equivalent(100.0, 80.0, period=180.0, lo=-90, hi=90) == pytest.approx(-80.0)


@given(st.lists(st.floats(-1e4, 1e4), min_size=1, max_size=50),
       st.sampled_from([90.0, 180.0, 360.0]))
def test_unwrap_sequence_steps_are_shortest(angles, period):
    out = unwrap_sequence(np.array(angles), period=period)
    steps = np.diff(np.concatenate([[0.0], out]))
    assert np.all(np.abs(steps) <= period / 2 + 1e-6)
    # same orientation modulo the period
    off = np.abs(((out - np.array(angles) + period / 2) % period) - period / 2)
    assert np.allclose(off, 0.0, atol=1e-6)


@pytest.mark.parametrize("tol", [0.01, 0.002, 0.0005])
def test_arc_points_within_chord_tolerance(tol):
    pts = arc_points((10.0, 0.0), (0.0, 10.0), (0.0, 0.0), clockwise=False, chord_tolerance=tol)
    assert tuple(pts[-1]) == (0.0, 10.0)
    full = np.vstack([[10.0, 0.0], pts])
    mid = (full[1:] + full[:-1]) / 2
    sagitta = 10.0 - np.hypot(mid[:, 0], mid[:, 1])
    assert sagitta.max() <= tol + 1e-12
    ang = np.arctan2(full[:, 1], full[:, 0])
    assert np.all(np.diff(ang) > 0)  # counter-clockwise


@pytest.mark.parametrize("model", ["rounded", "rectangle"])
@given(w=st.floats(0.2, 2.0), h=st.floats(0.05, 0.2))
def test_width_from_e_inverts_e_per_mm(model, w, h):
    e = e_per_mm(w, h, 1.75, model=model)
    assert width_from_e(e, h, 1.75, model=model) == pytest.approx(w, rel=1e-9)


def test_bead_area_is_slic3r_model():
    # PrusaSlicer Flow::mm3_per_mm: h (w - h) + pi h^2 / 4
    assert bead_area(0.45, 0.2) == pytest.approx(0.2 * 0.25 + math.pi * 0.04 / 4)


@pytest.mark.parametrize(("policy", "expected"), [
    ("xy", 1200.0),
    ("euclidean", 1200.0 * math.hypot(3.0, 4.0) / 3.0),
    ("inverse-time", 1200.0 / 3.0),
])
def test_feed_policies(policy, expected):
    f = feed_for_move(1200.0, 3.0, 4.0, policy=policy, rotary_feed=3600.0)
    assert f == pytest.approx(expected)


def _program(options: WriterOptions) -> str:
    em = Emitter(options)
    em.extend(header_lines(version="test", nozzle="ellipse:major=0.8,minor=0.3", machine="ttr",
                           options=options, mode="generated",
                           summary=[{"z": 0.2, "target_area": 100.0, "lost_area": 1.5}]))
    em.preamble()
    em.travel(10.0, 10.0, z=0.2, feed=9000, orientation=90.0)
    # a square: the nozzle turns at each corner, standing still
    for x, y, a in ((20.0, 10.0, 0.0), (20.0, 20.0, 90.0), (10.0, 20.0, 180.0),
                    (10.0, 10.0, 270.0)):
        em.extrude(x, y, feed=1800, width=0.45, height=0.2, orientation=a)
    em.retract(0.8, feed=2100)
    em.travel(30.0, 30.0, feed=9000, orientation=45.0)
    em.unretract(0.8, feed=2100)
    em.extrude(31.0, 31.0, feed=1800, e=0.05, orientation=45.0)
    em.postamble()
    return em.text()


@pytest.mark.parametrize(("name", "options"), [
    ("ellipse_xy_relative", WriterOptions(period=180.0)),
    ("ellipse_euclidean_absolute", WriterOptions(period=180.0, feed_policy="euclidean",
                                                 relative_e=False, letter="A")),
    ("round_inverse_time", WriterOptions(period=0.0, feed_policy="inverse-time")),
])
def test_golden_programs(name, options):
    text = _program(options)
    path = GOLDEN / f"{name}.gcode"
    if os.environ.get("PRINTABILITY_UPDATE_GOLDEN"):  # regenerate on purpose, then review
        path.write_text(text)
    assert path.exists(), f"golden file {path} missing (PRINTABILITY_UPDATE_GOLDEN=1 writes it)"
    assert text == path.read_text()
    parse_gcode(text.encode(), path=name)  # the reader accepts what the writer writes


def test_round_nozzle_never_gets_a_rotary_word():
    text = _program(WriterOptions(period=0.0))
    body = [ln for ln in text.splitlines() if not ln.startswith(";")]
    assert not any(" C" in ln.split(";")[0] for ln in body)


def test_square_turns_the_least():
    text = _program(WriterOptions(period=180.0))
    cs = [float(w[1:]) for ln in text.splitlines() if not ln.startswith(";")
          for w in ln.split(";")[0].split() if w.startswith("C")]
    # orientations 90, 0, 90, 180, 270 with an ellipse (period 180): steps of 90 at most
    assert all(abs(b - a) <= 90.0 + 1e-9 for a, b in itertools.pairwise(cs))


def test_relative_e_carries_rounding():
    em = Emitter(WriterOptions(e_decimals=3))
    em.preamble()
    em.travel(0.0, 0.0, feed=6000)
    total = 0.0
    for i in range(1, 200):
        total += em.extrude(i * 0.01, 0.0, feed=1200, e=0.00123)
    written = sum(float(w[1:]) for ln in em.lines for w in ln.split() if w.startswith("E")
                  and ln.startswith("G1 X"))
    assert written == pytest.approx(total, abs=1e-3)


def test_arc_refuses_to_turn():
    em = Emitter(WriterOptions(period=180.0))
    em.travel(0.0, 0.0, feed=6000, orientation=0.0)
    em.arc(10.0, 0.0, 5.0, 0.0, clockwise=True, feed=1200, e=0.5, length=15.7, orientation=0.0)
    assert em.lines[-1].startswith("G2 ") and " C" not in em.lines[-1]
    with pytest.raises(ValueError, match="linearised"):
        em.arc(0.0, 0.0, -5.0, 0.0, clockwise=True, feed=1200, e=0.5, length=15.7,
               orientation=30.0)


def test_unwind_on_travel_brings_axis_back():
    em = Emitter(WriterOptions(period=360.0, unwind=True))
    em.travel(0.0, 0.0, feed=6000, orientation=0.0)
    for k in range(1, 6):  # keep turning the same way while printing
        em.extrude(float(k), 0.0, feed=1200, e=0.01, orientation=k * 170.0)
    assert em.angle > 360.0
    em.travel(50.0, 50.0, feed=6000, orientation=em.angle)
    assert abs(em.angle) <= 180.0


@pytest.mark.parametrize(("raw", "kwargs", "expected"), [
    (b"G1 X10 Y20 E0.5 ; perimeter\r\n", {"add": ["C12.5"]},
     b"G1 X10 Y20 E0.5 C12.5 ; perimeter\r\n"),
    (b"g1  x10\ty20 e.5\n", {"replace": {"E": "E0.25"}}, b"g1  x10\ty20 E0.25\n"),
    (b"G1 X1 Y2 E3 F1500", {"drop": ["F"], "add": ["C1"]}, b"G1 X1 Y2 E3 C1"),
    (b"G1 X1 Y2\n", {"replace": {"E": "E1"}}, b"G1 X1 Y2 E1\n"),
])
def test_edit_line_keeps_every_other_byte(raw, kwargs, expected):
    assert edit_line(raw, **kwargs) == expected


@pytest.mark.parametrize(("raw", "value"), [
    (b"G1 X1.5 Y2 E0.0123\n", 0.0123), (b"G1  X1.5 E.5 F1800 ; perimeter\r\n", 0.5),
    (b"G1 E-0.8 F2100\n", -0.8), (b"G1 X1 Y2 E3", 3.0)])
@pytest.mark.parametrize("add", [(), ("C12.5",)])
def test_edit_e_is_edit_line_in_one_pass(raw, value, add):
    """The line edit_line makes (E replaced in place, words added after the last), and the
    value the line had."""
    line, old = edit_e(raw, lambda v: format_number(v * 2, 5), add=add)
    assert old == value
    assert line == edit_line(raw, replace={"E": "E" + format_number(value * 2, 5)},
                             add=list(add))


@pytest.mark.parametrize("raw", [b"G1 X1 Y2\n", b"N12 G1 X1 E2*57\n", b"M104 S200\n"])
def test_edit_e_leaves_other_lines_to_edit_line(raw):
    assert edit_e(raw, lambda v: "0") is None


@pytest.mark.parametrize("value", [float("inf"), float("-inf"), float("nan")])
def test_no_non_finite_number_is_ever_written(value):
    with pytest.raises(ValueError, match="non-finite"):
        format_number(value, 3)


@pytest.mark.parametrize(("changes", "match"), [
    ({"letter": "Q"}, "rotary letter"), ({"letter": "AB"}, "rotary letter"),
    ({"feed_policy": "fast"}, "feed policy"), ({"bead_model": "oval"}, "bead model"),
    ({"period": -1.0}, "period"),
])
def test_bad_writer_options_are_input_errors(changes, match):
    """A bad --letter (or other writer option) is the user's error: InputError, which the CLI
    prints as one paragraph (it was a plain ValueError and a traceback); still a ValueError."""
    from printability.base.errors import InputError

    with pytest.raises(InputError, match=match) as info:
        WriterOptions(**changes)
    assert isinstance(info.value, ValueError)

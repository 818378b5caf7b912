"""The print-time model (gcode.printtime, Klipper's look-ahead replayed) against closed forms;
its agreement with the real Klipper is tests/firmware/test_printtime_klipper.py."""

from __future__ import annotations

import math

import pytest

from gcode import parse_gcode
from gcode.flavors import PlannerLimits, RotaryAxis
from gcode.printtime import estimate_print_time, format_duration

LIMITS = PlannerLimits(max_velocity=300.0, max_accel=3000.0, square_corner_velocity=5.0)
AXIS = RotaryAxis(max_speed=360.0, acceleration=3600.0, corner_velocity=30.0)


def _t(text: str, **kw) -> float:
    return estimate_print_time(parse_gcode(("G90\nM83\nG1 F6000\n" + text).encode()),
                               limits=kw.get("limits", LIMITS),
                               rotary=kw.get("rotary", AXIS)).total


def _base() -> float:
    return _t("")


def test_a_straight_move_is_a_trapezoid():
    # from rest to rest: d/v + v/A (speeding up and slowing down each take v/A)
    v, a = 100.0, 3000.0
    assert _t("G1 X100\n") - _base() == pytest.approx(100 / v + v / a, rel=1e-9)


def test_a_short_move_keeps_the_minimum_cruise_ratio():
    # Klipper's minimum_cruise_ratio 0.5: a 1 mm move peaks at v² = A·d/2 and cruises half
    # its length (klippy v0.13 in batch mode plans 0.03873 s: tests/firmware)
    v = math.sqrt(3000.0 * 1.0 / 2)
    t = 2 * (v * v / 6000.0) / (v / 2) + 0.5 / v
    assert _t("G4 P0\nG1 X1\n") - _base() == pytest.approx(t, rel=1e-9)
    assert t == pytest.approx(0.03873, abs=1e-5)


def test_a_rotation_only_move_reads_f_as_degrees_per_minute():
    # 90° at F600 = 10 °/s: 9 s plus the ramp at the axis's acceleration
    t = _t("G1 C90 F600\n") - _base()
    assert t == pytest.approx(90 / 10 + 10 / 3600, rel=1e-9)
    # without its own F it would inherit the XY feed (F6000 = 100 °/s)
    assert _t("G1 C90\n") - _base() < t / 5


def test_the_axis_limits_cap_a_rotation():
    t = _t("G1 C90 F60000\n") - _base()  # asks 1000 °/s; the axis gives 360 °/s
    assert t == pytest.approx(90 / 360 + 360 / 3600, rel=1e-9)


def test_a_rotation_only_move_is_a_full_stop():
    straight = _t("G1 X50 E1\nG1 X100 E1\n")
    with_turn = _t("G1 X50 E1\nG1 C10 F21600\nG1 X100 E1 F6000\n")
    # two trapezoids instead of one (v/A more) and the turn; klippy v0.13 plans 0.149004 s
    # more (1.182337 against 1.033333 s; tests/firmware)
    assert with_turn - straight == pytest.approx(1.182337 - 1.033333, abs=2e-6)
    assert with_turn - straight > 100.0 / 3000.0 + 2 * math.sqrt(10 / 3600.0) * 0.99


def test_corners_are_taken_at_the_square_corner_velocity():
    square = _t("G1 X50\nG1 Y50\nG1 X0\nG1 Y0\n") - _base()
    line = _t("G1 X200\n") - _base()
    assert square > line


def test_dwell_and_acceleration_commands():
    assert _t("G4 P1500\n") - _base() == pytest.approx(1.5)
    slow = _t("M204 S500\nG1 X100\n") - _base()
    assert slow == pytest.approx(100 / 100 + 100 / 500, rel=1e-9)
    klipper = _t("SET_VELOCITY_LIMIT ACCEL=500\nG1 X100\n") - _base()
    assert klipper == pytest.approx(slow, rel=1e-12)


def test_absurd_limits_are_refused():
    with pytest.raises(ValueError, match="max_accel"):
        PlannerLimits(max_accel=0.0)
    with pytest.raises(ValueError, match="minimum_cruise_ratio"):
        PlannerLimits(minimum_cruise_ratio=1.0)


def test_format_duration():
    assert format_duration(41.4) == "41s"
    assert format_duration(125) == "2m 05s"
    assert format_duration(3723) == "1h 02m 03s"

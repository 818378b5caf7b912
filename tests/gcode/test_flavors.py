"""Firmware flavors (gcode.flavors): each owns how its rotary axis is declared, what F means,
which words it takes; machine profiles name them and carry the axis's limits."""

from __future__ import annotations

import math

import pytest

from gcode.flavors import FLAVORS, KlipperFlavor, RotaryAxis, flavor_named
from gcode.rotary import feed_for_move
from printability.errors import FileFormatError, InputError
from printability.model.machine import DEFAULT_BED, parse_machine
from printability.options import FLAVORS as FLAVOR_REGISTRY


def test_registry_and_flavor_types_agree():
    assert tuple(FLAVORS) == FLAVOR_REGISTRY.choices
    for name, flavor in FLAVORS.items():
        assert flavor.name == name
        assert FLAVOR_REGISTRY[name] == flavor.description


def test_klipper_registers_the_axis_and_never_uses_g92_for_it():
    axis = RotaryAxis(letter="C", max_speed=400.0, acceleration=5000.0, corner_velocity=25.0)
    lines = KlipperFlavor().declare_rotary(axis)
    words = [ln.split(";")[0].split() for ln in lines]
    # SET_POSITION is refused while registered: unregister, set, register (in that order)
    assert words[0] == ["MANUAL_STEPPER", "STEPPER=c", "GCODE_AXIS="]
    set_at = next(i for i, w in enumerate(words) if "SET_POSITION=0" in w)
    reg_at = next(i for i, w in enumerate(words) if "GCODE_AXIS=C" in w)
    assert 0 < set_at < reg_at
    assert {"LIMIT_VELOCITY=400", "LIMIT_ACCEL=5000",
            "INSTANTANEOUS_CORNER_VELOCITY=25"} <= set(words[reg_at])
    assert not any(w and w[0] == "G92" for w in words)
    assert not KlipperFlavor().rotary_words_allowed("G92")


@pytest.mark.parametrize("name", ["marlin", "reprap", "generic"])
def test_other_flavors_zero_the_axis_with_g92(name):
    lines = flavor_named(name).declare_rotary(RotaryAxis(letter="A"))
    assert [ln.split(";")[0].strip() for ln in lines] == ["G92 A0"]


@pytest.mark.parametrize("name", list(FLAVORS))
def test_no_flavor_takes_a_rotary_word_on_arcs(name):
    f = flavor_named(name)
    assert f.rotary_words_allowed("G1") and f.rotary_words_allowed("G0")
    assert not f.rotary_words_allowed("G2") and not f.rotary_words_allowed("G3")
    assert not f.inverse_time  # none of the four has G93


def test_unknown_flavor_lists_the_known_ones():
    with pytest.raises(ValueError, match="marlin, klipper, reprap, generic"):
        flavor_named("smoothie")


@pytest.mark.parametrize("kw", [{"max_speed": 0.0}, {"acceleration": math.inf},
                                {"corner_velocity": -1.0}, {"min_angle": 10.0, "max_angle": 0.0},
                                {"letter": "Q"}, {"stepper": "c d"}])
def test_rotary_axis_refuses_absurd_values(kw):
    with pytest.raises(ValueError):
        RotaryAxis(**kw)


def test_rotation_feed_is_degrees_per_minute():
    assert RotaryAxis(max_speed=360.0).rotation_feed == 21600.0


def test_euclidean_feed_never_asks_the_axis_for_more_than_its_speed():
    # a 90° turn over 0.05 mm at 30 mm/s: the XY time is 0.1 ms, the turn needs 0.25 s at
    # 360 °/s; F follows the turn (F2018025 before)
    f = feed_for_move(1800.0, 0.05, 90.0, policy="euclidean", rotary_feed=21600.0)
    length = math.hypot(0.05, 90.0)
    assert f == pytest.approx(length / (90.0 / 21600.0))
    # a gentle turn keeps the XY speed exactly
    f = feed_for_move(1800.0, 10.0, 1.0, policy="euclidean", rotary_feed=21600.0)
    assert f == pytest.approx(1800.0 * math.hypot(10.0, 1.0) / 10.0)


def test_builtin_specs_have_a_bed_and_no_stated_flavor():
    for spec in ("xy", "ttr", "ttr:min=-90,max=90"):
        m = parse_machine(spec)
        assert m.bed == DEFAULT_BED
        assert m.flavor is None
        assert m.firmware().name == "marlin"
        assert m.firmware("klipper").name == "klipper"  # a file's own flavor is followed
    assert parse_machine("ttr:min=-90,max=90").rotary_axis.max_angle == 90.0
    assert math.isinf(parse_machine("ttr").rotary_axis.max_angle)


def test_profile_rotary_limits(tmp_path):
    prof = tmp_path / "m.toml"
    prof.write_text('[machine]\nkind = "ttr"\n[rotary]\nmax_speed = 500\nacceleration = 8000\n'
                    'corner_velocity = 40\nstepper = "nozzle_turn"\n[firmware]\n'
                    'flavor = "klipper"\n')
    m = parse_machine(str(prof))
    assert m.firmware().name == "klipper"
    assert m.feed_policy_for(m.firmware()) == "xy"
    a = m.rotary_axis
    assert (a.max_speed, a.acceleration, a.corner_velocity, a.stepper) == \
        (500.0, 8000.0, 40.0, "nozzle_turn")


@pytest.mark.parametrize(("body", "match"), [
    ("max_speed = 0", "max_speed expects"),
    ("max_speed = nan", "max_speed"),
    ("acceleration = -5", "acceleration expects"),
    ("corner_velocity = 1e9", "corner_velocity expects"),
    ('stepper = "a b"', "stepper expects"),
    ("speed = 3", "unknown key 'speed'"),
])
def test_profile_rotary_limits_absurd(tmp_path, body, match):
    prof = tmp_path / "m.toml"
    prof.write_text(f'[machine]\nkind = "ttr"\n[rotary]\n{body}\n')
    with pytest.raises(InputError, match=match) as exc:
        parse_machine(str(prof))
    assert str(prof) in str(exc.value)


def test_profile_bed_must_be_ordered(tmp_path):
    prof = tmp_path / "m.toml"
    prof.write_text('[machine]\nkind = "ttr"\n[bed]\nx = [200.0, 0.0]\ny = [0.0, 200.0]\n')
    with pytest.raises(FileFormatError, match=r"\[bed\]"):
        parse_machine(str(prof))

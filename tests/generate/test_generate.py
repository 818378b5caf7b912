"""``printability generate``: walls and infill inside what the nozzle can print, on real parts."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import shapely
import shapely.affinity
from shapely.geometry import Polygon

from gcode import parse_gcode
from printability.errors import InputError
from printability.generate import GenerateOptions, generate_gcode
from printability.mmc import compute_mmc
from printability.model.geometry import as_region
from printability.model.layers import Layer, LayerStack
from printability.model.machine import parse_machine
from printability.model.nozzle import parse_nozzle
from printability.planning.check import check_deposition, extrusion_chords
from printability.sources import load_layers

ELLIPSE = "ellipse:major=0.8,minor=0.3"
GOLDEN = Path(__file__).with_name("golden")
ROOT = Path(__file__).resolve().parents[2]
TTR_PROFILE = ROOT / "printability" / "data" / "machines" / "ttr.toml"
# the parts keep their own coordinates (a machine without a bed), so the checks compare the
# G-code with the layers as they are
NO_BED = dataclasses.replace(parse_machine("ttr"), bed=None)


def _stack(*regions, height=0.2) -> LayerStack:
    return LayerStack(tuple(Layer(z=height * (i + 1), height=height, region=as_region(r), index=i)
                            for i, r in enumerate(regions)), source="test")


def _l_shape() -> Polygon:
    # an L (block and base) with a 0.5 mm thin rib standing on the base: the ellipse threads
    # the rib only moving along its major axis (0.3 mm wide bead)
    return Polygon([(0, 0), (12, 0), (12, 2), (6.5, 2), (6.5, 8), (6, 8), (6, 2), (4, 2),
                    (4, 8), (0, 8)])


@pytest.mark.parametrize(("name", "nozzle", "machine", "options"), [
    ("l_shape_ellipse_ttr", ELLIPSE, "ttr", GenerateOptions(center=False)),
    ("l_shape_round_xy", "circle:d=0.4", "xy", GenerateOptions(center=False, relative_e=False)),
    ("l_shape_ellipse_profile", ELLIPSE, str(TTR_PROFILE),
     GenerateOptions(feed_policy="euclidean", unwind=True)),
])
def test_golden(name, nozzle, machine, options):
    text, _ = generate_gcode(_stack(_l_shape(), _l_shape()), nozzle, machine, options=options)
    text = text.replace(str(TTR_PROFILE), "ttr.toml")
    path = GOLDEN / f"{name}.gcode"
    if os.environ.get("PRINTABILITY_UPDATE_GOLDEN"):
        path.write_text(text)
    assert path.exists(), f"golden file {path} missing (PRINTABILITY_UPDATE_GOLDEN=1 writes it)"
    assert text == path.read_text()


def _check(stack: LayerStack, nozzle: str, text: str, min_cover: float) -> None:
    g = parse_gcode(text.encode())
    assert len(g.layers) == len(stack)
    chords = extrusion_chords(g)
    noz = parse_nozzle(nozzle)
    reports = check_deposition(chords, [layer.region for layer in stack], noz, keep_union=True)
    assert len(reports) == len(stack)
    for r in reports:
        assert r.max_outside <= 1e-3 + 2e-4, f"layer {r.layer}: {r.max_outside} mm outside G"
        s = compute_mmc(stack[r.layer].region, noz, "ttr").as_built
        covered = s.intersection(r.deposited).area / s.area
        assert covered >= min_cover, f"layer {r.layer}: {covered:.3f} of S deposited"


def test_generate_calibration_cube(shared_data):
    layers = load_layers(shared_data / "stl" / "CalibrationCube.stl", layer_height=0.2)
    stack = LayerStack(tuple(layers.layers[::40]), source=layers.source)
    text, res = generate_gcode(stack, ELLIPSE, NO_BED, options=GenerateOptions(center=False))
    assert res.rotations > 0 and res.extruded_length > 0
    _check(stack, ELLIPSE, text, 0.95)


@pytest.mark.parametrize("name", [
    "saw-grip-slotwidth-1-5mm--rotated_outline_mesh0_z14500.txt",
    "OpenRC-spur-gear--rotated_outline_mesh0_z700.txt",
])
def test_generate_real_slices(shared_data, name):
    stack = load_layers(shared_data / "slices" / name)
    text, _ = generate_gcode(stack, ELLIPSE, NO_BED, options=GenerateOptions(center=False))
    _check(stack, ELLIPSE, text, 0.90)


def test_round_nozzle_writes_no_rotary_word():
    text, res = generate_gcode(_stack(_l_shape()), "circle:d=0.4", "ttr",
                               options=GenerateOptions(center=False))
    assert res.rotations == 0
    g = parse_gcode(text.encode())
    assert not (g.words["letter"] == ord("C")).any()


def test_the_slot_is_threaded_by_the_ellipse_not_by_a_wide_round_nozzle():
    """The 0.5 mm rib: the ellipse (0.3 mm across when moving along its major axis) prints
    in it, a 0.8 mm round nozzle cannot enter it at all."""
    slot = shapely.box(6.0, 2.3, 6.5, 8.0)
    for nozzle, expect in ((ELLIPSE, True), ("circle:d=0.8", False)):
        text, _ = generate_gcode(_stack(_l_shape()), nozzle, "ttr",
                                 options=GenerateOptions(center=False))
        ch = extrusion_chords(parse_gcode(text.encode()))
        mid = shapely.points((ch["x0"] + ch["x1"]) / 2, (ch["y0"] + ch["y1"]) / 2)
        assert bool(shapely.contains(slot, mid).any()) is expect, nozzle


@pytest.mark.parametrize(("flavor", "expected"), [
    ("marlin", ["M104 S215", "M109 S215", "M190 S60"]),
    ("reprap", ["G10 P0 S215 R215", "M116"]),
])
def test_start_gcode_per_flavor_uses_profile_temperatures(tmp_path, flavor, expected):
    text = TTR_PROFILE.read_text().replace('flavor = "marlin"', f'flavor = "{flavor}"')
    prof = tmp_path / "m.toml"
    prof.write_text(text)
    out, _ = generate_gcode(_stack(_l_shape()), ELLIPSE, str(prof))
    for line in expected:
        assert line in out.splitlines()
    assert "G1 E-0.8 F2100" in out.splitlines()  # retraction 0.8 mm at 35 mm/s


def test_bad_profile_value(tmp_path):
    prof = tmp_path / "m.toml"
    prof.write_text(TTR_PROFILE.read_text().replace("perimeter = 30.0", 'perimeter = "fast"'))
    with pytest.raises(InputError, match=r"\[speeds\] perimeter"):
        generate_gcode(_stack(_l_shape()), ELLIPSE, str(prof))


def test_cli_generate(tmp_path, shared_data):
    out = tmp_path / "part.gcode"
    gear = shared_data / "slices" / "OpenRC-spur-gear--rotated_outline_mesh0_z700.txt"
    r = subprocess.run([sys.executable, "-m", "printability", "generate", str(gear),
                        "-n", ELLIPSE, "-m", str(TTR_PROFILE), "-o", str(out)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    g = parse_gcode(out.read_bytes())
    assert g.moves["is_extrusion"].sum() > 100
    # centred on the profile's 220 x 220 bed
    ext = g.moves[g.moves["is_extrusion"]]
    assert np.all((ext["x1"] > 0) & (ext["x1"] < 220) & (ext["y1"] > 0) & (ext["y1"] < 220))
    r2 = subprocess.run([sys.executable, "-m", "printability", "generate", str(tmp_path / "no.stl"),
                         "-n", ELLIPSE, "-m", "ttr", "-o", str(tmp_path / "x.gcode")],
                        capture_output=True, text=True, timeout=600)
    assert r2.returncode == 1 and r2.stderr.startswith("printability: error:")
    assert not (tmp_path / "x.gcode").exists()


@pytest.mark.parametrize("machine", ["ttr:min=-90,max=90", "ttr:min=0,max=30", "xy"])
def test_limited_axes_keep_limits_and_mmc(machine):
    stack = _stack(_l_shape())
    text, _ = generate_gcode(stack, ELLIPSE, machine, options=GenerateOptions(center=False))
    g = parse_gcode(text.encode())
    c = g.words["value"][g.words["letter"] == ord("C")]
    if machine == "xy":
        assert c.size == 0
    else:
        lo, hi = (float(v.split("=")[1]) for v in machine.split(":")[1].split(","))
        assert c.min() >= lo - 1e-9 and c.max() <= hi + 1e-9
    reports = check_deposition(extrusion_chords(g), [stack[0].region], parse_nozzle(ELLIPSE))
    assert reports[0].max_outside <= 1e-3 + 2e-4


def _extrusion_bounds(text: str) -> tuple[float, float, float, float]:
    ch = extrusion_chords(parse_gcode(text.encode()))
    xs = np.concatenate([ch["x0"], ch["x1"]])
    ys = np.concatenate([ch["y0"], ch["y1"]])
    return xs.min(), xs.max(), ys.min(), ys.max()


@pytest.mark.parametrize("machine", ["ttr", "xy", "ttr:min=-90,max=90", str(TTR_PROFILE)])
def test_a_part_around_the_origin_lands_in_the_middle_of_the_bed(machine):
    # an STL is often modelled around the origin: generate used to print it at x = -9.85
    part = shapely.affinity.translate(_l_shape(), -6.0, -4.0)
    text, _ = generate_gcode(_stack(part), ELLIPSE, machine)
    bx0, bx1, by0, by1 = parse_machine(machine).bed
    x0, x1, y0, y1 = _extrusion_bounds(text)
    assert bx0 < x0 < x1 < bx1 and by0 < y0 < y1 < by1
    assert (x0 + x1) / 2 == pytest.approx((bx0 + bx1) / 2, abs=0.5)


def test_a_part_larger_than_the_bed_is_a_clear_error():
    big = shapely.box(0, 0, 300, 10)
    with pytest.raises(InputError, match=r"part \(300\.0 mm × 10\.0 mm\) is larger than the bed"):
        generate_gcode(_stack(big), ELLIPSE, "ttr")


def test_a_part_off_the_bed_without_centring_is_a_clear_error():
    part = shapely.affinity.translate(_l_shape(), -20.0, 0.0)
    with pytest.raises(InputError, match="off the bed"):
        generate_gcode(_stack(part), ELLIPSE, "ttr", options=GenerateOptions(center=False))


def test_klipper_flavor_registers_the_axis_and_writes_no_g92_c(tmp_path):
    prof = tmp_path / "k.toml"
    prof.write_text(TTR_PROFILE.read_text().replace('flavor = "marlin"', 'flavor = "klipper"'))
    text, res = generate_gcode(_stack(_l_shape()), ELLIPSE, str(prof))
    lines = text.splitlines()
    assert res.rotations > 0
    assert not any(ln.startswith("G92 C") for ln in lines)
    reg = next(i for i, ln in enumerate(lines) if "GCODE_AXIS=C" in ln)
    first_c = next(i for i, ln in enumerate(lines) if ln.startswith("G1") and " C" in ln)
    assert reg < first_c
    assert "LIMIT_VELOCITY=360" in lines[reg]


def test_rotation_only_moves_carry_their_own_feed_and_the_next_move_restores_it():
    text, _ = generate_gcode(_stack(_l_shape()), ELLIPSE, "ttr")
    lines = [ln.split(";")[0].split() for ln in text.splitlines()]
    seen = 0
    for i, w in enumerate(lines):
        if w[:1] == ["G1"] and len(w) >= 2 and w[1].startswith("C") and \
                not any(x[0] in "XYZE" for x in w[1:]):
            assert any(x.startswith("F") for x in w), text.splitlines()[i]
            nxt = next(v for v in lines[i + 1:] if v[:1] in (["G1"], ["G0"]))
            assert any(x.startswith("F") for x in nxt)
            seen += 1
    assert seen > 0


def test_cli_says_which_layer_height_a_mesh_is_sliced_at(tmp_path, shared_data):
    out = tmp_path / "cube.gcode"
    r = subprocess.run([sys.executable, "-m", "printability", "generate",
                        str(shared_data / "stl" / "CalibrationCube.stl"), "-n", "circle:d=0.4",
                        "-m", "xy", "-o", str(out)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "slicing at 0.2 mm layers (give --layer-height to choose)" in " ".join(r.stderr.split())

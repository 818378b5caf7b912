"""The deposition record: swept footprints match an independent shapely sweep of the same
moves, and material outside the target is reported as an MMC violation with its location."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
import serial
import shapely
import shapely.affinity
from _sim_helpers import MiniHost, file_commands
from shapely.geometry import LineString, Point, box

from printability.model.layers import Layer, LayerStack
from simulators import Firmware, make_config, write_record
from simulators.transports import Link

PRUSA = "gcode/prusaslicer_2.7.4_marlin2_arcs.gcode"


def _run(commands: list[str], **kw) -> Firmware:
    cfg = make_config(**{k: v for k, v in kw.items() if k != "quad_segs"})
    cfg = replace(cfg, quad_segs=kw.get("quad_segs", 32))
    fw = Firmware(cfg)
    fw.connect()
    fw.receive("".join(c + "\n" for c in commands).encode())
    fw.run_sim()
    fw.drain()
    return fw


def _stream(commands: list[str], **kw) -> Firmware:
    """Through the printsim:// port with a host that numbers and checksums every line."""
    cfg = replace(make_config(**kw), quad_segs=32)
    ser = serial.serial_for_url("printsim://", timeout=0, do_not_open=True)
    ser.simulator = Link(cfg)
    ser.open()
    MiniHost(ser).stream(commands)
    ser.close()
    ser.simulator.firmware.drain()  # the last blocks print after their 'ok'
    return ser.simulator.firmware


def _arc_points(p0, p1, i, j, cw):
    """The arc as Marlin's plan_arc cuts it: chords of at most 1 mm, at least 72 per turn."""
    cx, cy = p0[0] + i, p0[1] + j
    r = math.hypot(i, j)
    a0 = math.atan2(p0[1] - cy, p0[0] - cx)
    a1 = math.atan2(p1[1] - cy, p1[0] - cx)
    d = a1 - a0
    if cw and d >= 0:
        d -= 2 * math.pi
    if not cw and d <= 0:
        d += 2 * math.pi
    n = max(1, math.ceil(abs(d) * r / 1.0), math.ceil(72 * abs(d) / (2 * math.pi)))
    t = np.linspace(0, 1, n + 1)
    pts = np.column_stack([cx + r * np.cos(a0 + d * t), cy + r * np.sin(a0 + d * t)])
    pts[-1] = p1
    return pts


def independent_sweep(commands: list[str], radius: float) -> dict[float, object]:
    """Extruded paths of a (subset of) G-code buffered by the nozzle radius, per layer.
    Written from the G-code semantics alone: no simulator code."""
    x = y = z = e = 0.0
    rel, erel = False, False
    layers: dict[float, list] = {}
    for c in commands:
        w = c.split()
        code = w[0].upper()
        args = {}
        for t in w[1:]:
            try:
                args[t[0].upper()] = float(t[1:])
            except ValueError:
                args[t[0].upper()] = None
        if code == "G90":
            rel = False
        elif code == "G91":
            rel = True
        elif code == "M82":
            erel = False
        elif code == "M83":
            erel = True
        elif code == "G92":
            e = args.get("E", e) if "E" in args else e
        elif code == "G28":
            x = y = z = 0.0
        elif code in ("G0", "G1", "G2", "G3"):
            nx = (x + args["X"] if rel else args["X"]) if args.get("X") is not None else x
            ny = (y + args["Y"] if rel else args["Y"]) if args.get("Y") is not None else y
            nz = (z + args["Z"] if rel else args["Z"]) if args.get("Z") is not None else z
            ne = e
            if args.get("E") is not None:
                ne = e + args["E"] if (rel or erel) else args["E"]
            if ne > e + 1e-12:
                if code in ("G2", "G3"):
                    pts = _arc_points((x, y), (nx, ny), args.get("I") or 0.0,
                                      args.get("J") or 0.0, code == "G2")
                    g = LineString(pts).buffer(radius, quad_segs=32)
                elif (nx, ny) == (x, y):
                    g = Point(x, y).buffer(radius, quad_segs=32)
                else:
                    g = LineString([(x, y), (nx, ny)]).buffer(radius, quad_segs=32)
                layers.setdefault(round(nz, 3), []).append(g)
            x, y, z, e = nx, ny, nz, ne
    return {k: shapely.union_all(v) for k, v in layers.items()}


def _rel_diff(a, b) -> float:
    return a.symmetric_difference(b).area / max(b.area, 1e-12)


SQUARE = ["M302 P1", "G28", "G1 Z0.2 F600", "G1 X10 Y10 F3000", "G1 X30 Y10 E1",
          "G1 X30 Y25 E2", "G3 X20 Y35 I-10 J0 E3", "G2 X10 Y25 I0 J-10 E4", "G1 X10 Y10 E5",
          "G1 X20 Y12", "G1 X25 Y20 E6", "G1 Z0.4", "G1 X12 Y12 E7", "G1 X28 Y12 E7.5"]


@pytest.mark.parametrize("d", [0.4, 0.6, 1.0])
def test_circle_deposition_matches_independent_sweep(d):
    fw = _run(SQUARE, nozzle=f"circle:d={d}")
    ref = independent_sweep(SQUARE, d / 2)
    rec = fw.record()
    assert [lr.z for lr in rec.layers] == sorted(ref)
    for lr in rec.layers:
        assert _rel_diff(lr.region, ref[round(lr.z, 3)]) < 0.005


def _ellipse(a: float, b: float, angle: float, x: float, y: float):
    g = shapely.affinity.scale(Point(0, 0).buffer(1.0, quad_segs=24), a, b, origin=(0, 0))
    return shapely.affinity.translate(shapely.affinity.rotate(g, angle, origin=(0, 0)), x, y)


@pytest.mark.parametrize(("mount", "turns"), [(0.0, [0, 90, 180, 270]), (30.0, [0, 0, 45, 45]),
                                              (0.0, [0, 360, 360, 0])])
def test_turning_ellipse_matches_dense_sampling(mount, turns):
    pts = [(10, 10), (20, 10), (20, 20), (10, 20), (10, 10)]
    cmds = ["M302 P1", "G28", "G1 Z0.2 F600", "G1 X10 Y10 C0 F3000"]
    for k in range(4):
        cmds.append(f"G1 X{pts[k + 1][0]} Y{pts[k + 1][1]} C{turns[k]} E{k + 1}")
    fw = _run(cmds, nozzle=f"ellipse:major=1.2,minor=0.4,angle={mount}")
    pieces = []
    c_prev = 0.0
    for k in range(4):
        (x0, y0), (x1, y1) = pts[k], pts[k + 1]
        for t in np.linspace(0, 1, 401):
            pieces.append(_ellipse(0.6, 0.2, mount + c_prev + (turns[k] - c_prev) * t,
                                   x0 + (x1 - x0) * t, y0 + (y1 - y0) * t))
        c_prev = turns[k]
    ref = shapely.union_all(pieces)
    (lr,) = fw.record().layers
    assert _rel_diff(lr.region, ref) < 0.01


def test_stationary_extrusion_deposits_the_footprint():
    fw = _run(["M302 P1", "G28", "G1 X5 Y5 Z0.2 C30", "G1 E1"], nozzle="rect:w=1,h=0.5")
    (lr,) = fw.record().layers
    ref = shapely.affinity.translate(shapely.affinity.rotate(box(-0.5, -0.25, 0.5, 0.25), 30,
                                                             origin=(0, 0)), 5, 5)
    assert _rel_diff(lr.region, ref) < 1e-9


def test_cold_extrusion_is_prevented():
    fw = _run(["G28", "G1 X5 Y5 Z0.2", "G1 X10 E1"])
    assert fw.record().layers == ()


def test_real_file_deposition_matches_independent_sweep(shared_data):
    cmds = file_commands(shared_data / PRUSA, limit=2500)
    fw = _stream(cmds, nozzle="circle:d=0.4", profile="marlin-advanced")
    assert [t for n, t in fw.executed if n is not None and n >= 1] == cmds
    ref = independent_sweep(cmds, 0.2)
    rec = fw.record()
    assert len(rec.layers) >= 3
    assert {lr.z for lr in rec.layers} == set(ref)
    for lr in rec.layers:
        assert _rel_diff(lr.region, ref[round(lr.z, 3)]) < 0.005, lr.z


TARGET = LayerStack((Layer(0.2, 0.2, shapely.MultiPolygon([box(50, 50, 70, 70)])),),
                    source="test-box")


def _bad_file(leave: bool) -> list[str]:
    cmds = ["M302 P1", "G28", "G1 Z0.2 F600", "G1 X51 Y51 F3000", "G1 X69 Y51 E1",
            "G1 X69 Y69 E2", "G1 X51 Y69 E3", "G1 X51 Y51 E4"]
    if leave:
        cmds += ["G1 X60 Y60", "G1 X80 Y60 E5"]  # leaves the part through the right edge
    return [*cmds, "G1 X55 Y55", "G1 X65 Y55 E6"]


def test_move_leaving_the_part_is_an_mmc_violation():
    fw = _stream(_bad_file(True), nozzle="circle:d=0.4", target=TARGET)
    rec = fw.record()
    (v,) = rec.violations
    assert v.z == pytest.approx(0.2)
    assert v.first_text == "G1 X80 Y60 E5"
    assert v.first_line == 10  # the host's line number of that move
    assert v.bbox == pytest.approx((70.0, 59.8, 80.2, 60.2), abs=0.01)
    assert v.area == pytest.approx(10 * 0.4 + math.pi * 0.04 / 2, rel=0.01)
    (lr,) = rec.layers
    assert lr.outside_area == pytest.approx(v.area)
    assert 0 < lr.coverage < 1


def test_good_file_has_no_violation_and_full_coverage_of_its_beads():
    rec = _stream(_bad_file(False), nozzle="circle:d=0.4", target=TARGET).record()
    assert rec.violations == ()
    (lr,) = rec.layers
    assert lr.outside_area == 0.0
    assert lr.coverage == pytest.approx(lr.area / 400.0)


def test_material_on_a_layer_the_target_lacks_is_all_outside():
    cmds = [*_bad_file(False), "G1 Z0.6", "G1 X60 Y60 E7", "G1 X61 Y60 E8"]
    rec = _stream(cmds, target=TARGET).record()
    (v,) = rec.violations
    assert v.z == pytest.approx(0.6) and v.first_text == "G1 X60 Y60 E7"


def test_record_written_atomically_as_json(tmp_path):
    fw = _stream(_bad_file(True), target=TARGET)
    path = write_record(fw.record(), tmp_path / "sub" / "rec.json")
    doc = json.loads(path.read_text())
    assert [os for os in tmp_path.joinpath("sub").iterdir()] == [path]  # no temporary left
    assert doc["units"] == "mm" and doc["target"] == "test-box"
    assert doc["log"] == [list(x) for x in fw.executed]
    assert doc["violations"][0]["first_line"] == 10
    region = shapely.from_wkt(doc["layers"][0]["region_wkt"])
    assert region.area == pytest.approx(doc["layers"][0]["deposited_area"], rel=1e-4)
    assert doc["stats"]["motion_time_s"] > 0


def test_kill_leaves_queued_blocks_unprinted():
    cmds = ["M302 P1", "G1 Z0.2 F600", "G1 X10 Y10 F3000",
            *[f"G1 X{10 + 5 * (i % 2)} Y{10 + i} E{i}" for i in range(1, 11)]]
    whole = _run(cmds).record()
    fw = Firmware(make_config())
    fw.connect()
    fw.receive("".join(c + "\n" for c in cmds).encode(), 0.0)
    fw.advance(0.0)
    fw.advance(1.0)  # the first moves run
    fw.receive(b"M112\n", 1.0)
    fw.advance(1.0)
    assert fw.halted  # the emergency parser acts although the command queue is full
    fw.drain()
    killed = fw.record()
    assert sum(lr.moves for lr in killed.layers) < sum(lr.moves for lr in whole.layers)

"""DXF source: drawings made here with ezdxf itself, units, chains, refusals."""

from __future__ import annotations

import math
from pathlib import Path

import ezdxf
import numpy as np
import pytest
import shapely

from printability.errors import FileFormatError
from printability.settings import Settings
from printability.sources.dxf import load_dxf_layers

SPLINE_FIT = [(300, 0), (320, 0), (320, 20), (300, 20), (300, 0)]


def _drawing(tmp_path: Path, insunits: int = 4, name: str = "part.dxf") -> Path:
    doc = ezdxf.new(units=insunits)
    msp = doc.modelspace()
    # A slot: two lines and two half circles, drawn as separate LINE/ARC entities
    # in no particular order or direction; 40 × 20 with round ends of radius 10.
    msp.add_line((0, 0), (40, 0))
    msp.add_line((0, 20), (40, 20))
    msp.add_arc((40, 10), 10, -90, 90)
    msp.add_arc((0, 10), 10, 90, 270)
    msp.add_circle((0, 10), 4)  # a hole in the slot
    # A plate with a round hole made of two bulged LWPOLYLINE segments (d = 6).
    msp.add_lwpolyline([(100, 0), (130, 0), (130, 20), (100, 20)], close=True)
    msp.add_lwpolyline([(112, 10, 0, 0, 1), (118, 10, 0, 0, 1)], format="xyseb", close=True)
    # An ellipse island (semi-axes 8 and 4) and a closed spline through fit points.
    msp.add_ellipse((200, 10), major_axis=(8, 0), ratio=0.5)
    msp.add_spline(SPLINE_FIT)
    # A block used twice.
    blk = doc.blocks.new("SQ")
    blk.add_lwpolyline([(0, 0), (5, 0), (5, 5), (0, 5)], close=True)
    msp.add_blockref("SQ", (400, 0))
    msp.add_blockref("SQ", (410, 0))
    # An old-style 2-D POLYLINE triangle (area 50).
    msp.add_polyline2d([(500, 0), (510, 0), (510, 10)], close=True)
    msp.add_text("label")
    path = tmp_path / name
    doc.saveas(path)
    return path


EXPECTED = {
    "slot": 40 * 20 + math.pi * 100 - math.pi * 16,
    "plate": 600 - math.pi * 9,
    "ellipse": math.pi * 8 * 4,
    "squares": 50.0,
}


def test_entities_chains_holes_blocks(tmp_path: Path):
    stack = load_dxf_layers(_drawing(tmp_path))
    region = stack[0].region
    assert len(region.geoms) == 7
    by_x = {round(g.bounds[0]): g for g in region.geoms}
    # Inscribed flattening: the area lost is at most perimeter × chord tolerance (0.002 mm).
    tol = Settings().chord_tolerance
    assert 0 <= EXPECTED["slot"] - by_x[-10].area <= (80 + 2 * math.pi * 14) * tol
    assert 0 <= by_x[100].area - EXPECTED["plate"] <= 2 * math.pi * 3 * tol
    assert 0 <= EXPECTED["ellipse"] - by_x[192].area <= 2 * math.pi * 8 * tol
    assert by_x[400].area == by_x[410].area == pytest.approx(25.0)
    assert by_x[500].area == pytest.approx(50.0)
    spline = next(g for g in region.geoms if 290 < g.centroid.x < 330)
    for x, y in SPLINE_FIT:  # a fit-point spline passes through its fit points
        assert spline.exterior.distance(shapely.Point(x, y)) < 1e-9
    assert stack.meta["insunits_name"] == "millimeters"
    assert stack.meta["loops_joined"] == 1
    assert stack.meta["skipped"] == {"TEXT": 1}
    assert not stack.meta["warnings"]


def test_flattening_within_chord_tolerance(tmp_path: Path):
    path = _drawing(tmp_path)
    for tol in (0.05, 0.001):
        region = load_dxf_layers(path, settings=Settings(chord_tolerance=tol))[0].region
        plate = next(g for g in region.geoms if round(g.bounds[0]) == 100)
        hole = np.asarray(plate.interiors[0].coords)
        r = np.hypot(hole[:, 0] - 115, hole[:, 1] - 10)
        # Vertices on the circle; chords inside it by at most tol.
        assert np.allclose(r, 3.0, atol=1e-9)
        assert abs(plate.area - EXPECTED["plate"]) <= 2 * math.pi * 3 * tol


def test_insunits_inches_and_override(tmp_path: Path):
    mm = load_dxf_layers(_drawing(tmp_path, insunits=4, name="mm.dxf"))
    path = _drawing(tmp_path, insunits=1)
    stack = load_dxf_layers(path)
    assert stack.meta["scale"] == pytest.approx(25.4)
    assert stack[0].area == pytest.approx(mm[0].area * 25.4**2, rel=1e-4)
    cm = load_dxf_layers(path, units="cm")
    assert cm.meta["scale"] == pytest.approx(10.0)
    assert any("overrides" in w for w in cm.meta["warnings"])


def test_unitless_is_read_as_mm_with_warning(tmp_path: Path):
    stack = load_dxf_layers(_drawing(tmp_path, insunits=0))
    assert stack.meta["scale"] == 1.0
    assert any("unitless" in w for w in stack.meta["warnings"])


def test_open_pieces_are_reported(tmp_path: Path):
    doc = ezdxf.new(units=4)
    msp = doc.modelspace()
    msp.add_lwpolyline([(0, 0), (10, 0), (10, 10)], close=True)
    msp.add_line((20, 0), (30, 0))
    msp.add_arc((30, 5), 5, -90, 45)
    path = tmp_path / "open.dxf"
    doc.saveas(path)
    stack = load_dxf_layers(path)
    assert stack[0].area == pytest.approx(50.0)
    assert any("2 open piece" in w for w in stack.meta["warnings"])


def test_hidden_layers_are_skipped(tmp_path: Path):
    doc = ezdxf.new(units=4)
    doc.layers.add("CONSTRUCTION").off()
    doc.layers.add("FROZEN").freeze()
    msp = doc.modelspace()
    msp.add_circle((0, 0), 5, dxfattribs={"layer": "CONSTRUCTION"})
    msp.add_circle((20, 0), 5, dxfattribs={"layer": "FROZEN"})
    msp.add_lwpolyline([(0, 0), (4, 0), (4, 4), (0, 4)], close=True)
    path = tmp_path / "layers.dxf"
    doc.saveas(path)
    stack = load_dxf_layers(path)
    assert stack[0].area == pytest.approx(16.0)
    assert sum(stack.meta["skipped"].values()) == 2


def test_no_closed_outline(tmp_path: Path):
    doc = ezdxf.new(units=4)
    doc.modelspace().add_line((0, 0), (1, 1))
    doc.modelspace().add_text("x")
    path = tmp_path / "lines.dxf"
    doc.saveas(path)
    with pytest.raises(FileFormatError, match=r"lines\.dxf: no closed outline.*1 open.*TEXT"):
        load_dxf_layers(path)


def test_not_a_dxf(tmp_path: Path):
    junk = tmp_path / "junk.dxf"
    junk.write_bytes(np.random.default_rng(3).bytes(3000))
    with pytest.raises(FileFormatError, match=r"junk\.dxf: expected a DXF drawing"):
        load_dxf_layers(junk)
    text = tmp_path / "text.dxf"
    text.write_text("hello\nworld\n")
    with pytest.raises(FileFormatError, match=r"text\.dxf"):
        load_dxf_layers(text)

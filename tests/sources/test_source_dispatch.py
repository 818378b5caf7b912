"""load_layers: reader choice by extension and content, option checks, registries."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import pytest
import shapely

from printability.errors import (
    FileFormatError,
    InputError,
    PrintabilityOSError,
    UnknownOptionError,
)
from printability.model.layers import LayerStack
from printability.model.nozzle import parse_nozzle
from printability.options import REGISTRIES, SOURCE_FORMATS, UNITS
from printability.settings import Settings
from printability.sources import EXTENSIONS, detect_format, load_layers
from printability.sources._common import UNIT_MM
from tests.conftest import SHARED_DATA


def _shared_inputs() -> list[str]:
    if not SHARED_DATA.is_dir():
        return []
    rels = [f"stl/{p.name}" for p in sorted((SHARED_DATA / "stl").glob("*.stl"))]
    rels += [f"svg/{p.name}" for p in sorted((SHARED_DATA / "svg").glob("*.svg"))]
    rels += [p.name for p in sorted(SHARED_DATA.glob("*.geojson"))]
    slices = sorted(p for p in (SHARED_DATA / "slices").glob("*.txt") if "LICENSE" not in p.name)
    rels += [f"slices/{p.name}" for p in slices[::25]]
    return rels


@pytest.mark.parametrize("rel", _shared_inputs())
def test_every_shared_input_through_load_layers(shared_data: Path, rel: str):
    path = shared_data / rel
    fmt = detect_format(path)
    kwargs = {"layer_height": 1.0} if fmt == "stl" else {"fit": 100.0} if fmt == "geojson" else {}
    stack = load_layers(path, **kwargs)
    assert stack.units == "mm" and stack.source == str(path)
    assert all(lay.area > 0 and lay.region.is_valid for lay in stack)
    if fmt == "stl":
        assert len(stack) >= 1 and stack.volume > 0
    else:
        assert stack.is_planar
    minx, miny, maxx, maxy = shapely.MultiPolygon(
        [g for lay in stack for g in lay.region.geoms]).bounds
    assert 0 < max(maxx - minx, maxy - miny) < 1000.0  # a printable size, in mm


def test_registries():
    assert REGISTRIES["source format"] is SOURCE_FORMATS
    assert REGISTRIES["unit"] is UNITS
    assert set(UNIT_MM) == set(UNITS.choices)
    assert set(EXTENSIONS.values()) <= set(SOURCE_FORMATS.choices)
    assert UNITS.check("IN") == "in"


@pytest.mark.parametrize(("rel", "kwargs", "fmt", "n_layers"), [
    ("stl/ThinWall.stl", {"layer_height": 0.25}, "stl", 20),
    ("svg/bootstrap_gear-fill.svg", {}, "svg", 1),
    ("japan_110m.geojson", {"fit": 150.0}, "geojson", 1),
    ("slices/ACAM-Base--scaled_outline_mesh0_z1100.txt", {}, "slices", 1),
])
def test_by_extension_and_by_content(shared_data: Path, tmp_path: Path, rel: str, kwargs,
                                     fmt: str, n_layers: int):
    src = shared_data / rel
    assert detect_format(src) == fmt
    stack = load_layers(src, **kwargs)
    assert isinstance(stack, LayerStack) and len(stack) == n_layers
    # The same bytes under a meaningless name are recognised from their content.
    anon = tmp_path / "input.dat"
    shutil.copyfile(src, anon)
    assert detect_format(anon) == fmt
    again = load_layers(anon, **kwargs)
    assert [lay.area for lay in again] == pytest.approx([lay.area for lay in stack])


def test_wkt_and_dxf_by_content(tmp_path: Path):
    import ezdxf

    wkt = tmp_path / "a.dat"
    wkt.write_text("POLYGON ((0 0, 3 0, 3 3, 0 3, 0 0))")
    assert detect_format(wkt) == "wkt" and load_layers(wkt)[0].area == pytest.approx(9.0)
    doc = ezdxf.new(units=4)
    doc.modelspace().add_circle((0, 0), 1.0)
    dxf = tmp_path / "b.dat"
    doc.saveas(dxf)
    assert detect_format(dxf) == "dxf"
    # Inscribed flattening loses at most perimeter × chord tolerance.
    assert 0 < math.pi - load_layers(dxf)[0].area <= 2 * math.pi * Settings().chord_tolerance


def test_forced_format(shared_data: Path, tmp_path: Path):
    src = tmp_path / "gear.xml"
    shutil.copyfile(shared_data / "svg" / "bootstrap_gear-fill.svg", src)
    assert load_layers(src, format="SVG")[0].area == pytest.approx(132.0, rel=1e-3)
    with pytest.raises(UnknownOptionError, match=r"source format 'png'.*stl, 3mf"):
        load_layers(src, format="png")


def test_geojson_options_pass_through(shared_data: Path, tmp_path: Path):
    path = tmp_path / "plate.geojson"
    path.write_text('{"type": "Polygon", "coordinates": [[[0, 0], [40, 0], [40, 20], [0, 0]]]}')
    with pytest.raises(InputError, match="geographic=False"):
        load_layers(path)
    assert load_layers(path, geographic=False)[0].area == pytest.approx(400.0)
    japan = load_layers(shared_data / "japan_10m.geojson", keep_largest=4, fit=150.0)
    assert len(japan[0].region.geoms) == 4
    clipped = load_layers(shared_data / "japan_10m.geojson", clip=(128, 30, 146, 46),
                          map_scale=0.5)
    assert clipped.meta["scale"] == 0.5


def test_options_that_do_not_apply(shared_data: Path):
    # the options as the CLI spells them (issue #23: layer_height named no option a user has)
    with pytest.raises(InputError, match="--layer-height do not apply to svg input; it "
                                         "accepts --units, --fit"):
        load_layers(shared_data / "svg" / "bootstrap_gear-fill.svg", layer_height=0.2)
    with pytest.raises(InputError, match="--map-scale do not apply to stl"):
        load_layers(shared_data / "stl" / "ThinWall.stl", map_scale=1.0)
    with pytest.raises(InputError, match="--layer-height must be a positive number of mm"):
        load_layers(shared_data / "stl" / "ThinWall.stl", layer_height=-1.0)
    with pytest.raises(UnknownOptionError, match="unknown unit 'furlong'"):
        load_layers(shared_data / "stl" / "ThinWall.stl", units="furlong")


def test_unknown_missing_and_directory(tmp_path: Path):
    odd = tmp_path / "notes.bin"
    odd.write_bytes(b"\x00\x01 just some bytes \xff")
    with pytest.raises(FileFormatError, match=r"notes\.bin: cannot tell what kind of file") as e:
        load_layers(odd)
    # what a CLI user can do (the CLI has no format option), then the library's keyword
    assert "give the file one of these extensions; from Python, load_layers(..., format=)" \
        in str(e.value)
    with pytest.raises(PrintabilityOSError, match="no such file"):
        load_layers(tmp_path / "absent.stl")
    with pytest.raises(PrintabilityOSError, match="not a regular file"):
        load_layers(tmp_path)


def test_gcode_goes_to_the_gcode_reader(shared_data: Path):
    pytest.importorskip("printability.sources.gcode")
    path = min((shared_data / "gcode").glob("*.gcode"), key=lambda p: p.stat().st_size)
    assert detect_format(path) == "gcode"
    stack = load_layers(path)
    assert len(stack) > 1 and all(lay.area > 0 for lay in stack)
    with pytest.raises(InputError, match="--fit do not apply to gcode"):
        load_layers(path, fit=10.0)


def test_svg_polygon_nozzle(tmp_path: Path):
    # printability.model.nozzle reads polygon nozzles through load_svg_region.
    svg = tmp_path / "tip.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="2mm" height="1mm" '
                   'viewBox="0 0 2 1"><ellipse cx="1" cy="0.5" rx="0.4" ry="0.15"/></svg>')
    nozzle = parse_nozzle(f"polygon:{svg}")
    exact = math.pi * 0.4 * 0.15
    assert 0 < exact - nozzle.area <= 2 * math.pi * 0.4 * Settings().chord_tolerance

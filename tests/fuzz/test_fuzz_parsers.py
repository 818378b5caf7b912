"""Hypothesis strategies for every input kind, through the readers in this process (issue #24,
item 5): G-code (the post-processor's reader and the host's), SVG, WKT, GeoJSON, slice
outlines, binary STL, nozzle and machine SPECs. Whatever the input, a reader returns or raises
a :class:`~printability.errors.PrintabilityError` whose message is one short paragraph."""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gcode import parse_gcode
from machine_io import parse_program
from printability.errors import PrintabilityError
from printability.model.machine import parse_machine
from printability.model.nozzle import parse_nozzle
from printability.sources.geo import load_geojson_layers, load_wkt_layers
from printability.sources.mesh import load_mesh
from printability.sources.slices import load_slice_layers
from printability.sources.svg import load_svg_layers

# Numbers as files write them, and as fuzzers and broken exporters do.
NUMBERS = st.one_of(
    st.integers(-10**6, 10**6).map(str),
    st.floats(-1e4, 1e4, allow_nan=False).map(lambda v: f"{v:.4f}"),
    st.sampled_from(["nan", "inf", "-inf", "1e309", "-1e309", "1e-320", "-0", "9" * 400,
                     ".", "-", "1.5.5", "", "1e15", "0x1f", "+.5", "5."]),
    st.floats().map(repr),
)
JUNK = st.sampled_from(["\x00", "\x01", "\x1b", "\x7f", "\t", " ", "*", ";", "\"", "\u202e",
                        "é", "[", "]", ",", "="])

COMMANDS = st.sampled_from(["G0", "G1", "G2", "G3", "G4", "G90", "G91", "G92", "G28", "G20",
                            "G21", "M82", "M83", "M104", "M109", "M106", "M110", "M117", "T0",
                            "T1", "g1", "G01", "N5 G1", "EXCLUDE_OBJECT_DEFINE", "SET_TOOL", "",
                            "X", ";LAYER_CHANGE", ";Z:", ";TYPE:External perimeter"])
WORD = st.tuples(st.sampled_from(list("XYZEFIJRPSABCUVWNK")), NUMBERS).map("".join)
LINE = st.tuples(COMMANDS, st.lists(st.one_of(WORD, JUNK), max_size=8),
                 st.sampled_from(["", " ; comment", "*12", " ;\xff"])).map(
    lambda t: (t[0] + " " + " ".join(t[1]) + t[2]))
GCODE = st.lists(LINE, min_size=1, max_size=40).map(lambda lines: "\n".join(lines))

# FUZZ_EXAMPLES=2000 explores more (a developer's knob; CI runs the default)
FUZZ = settings(max_examples=int(os.environ.get("FUZZ_EXAMPLES", "60")),
                suppress_health_check=[HealthCheck.too_slow], deadline=None)


def _check(exc: PrintabilityError) -> None:
    message = str(exc)
    assert message and len(message) < 1500, message[:300]


@FUZZ
@given(GCODE, st.sampled_from(["\n", "\r\n", "\r"]))
def test_gcode_reader_takes_anything(text, newline):
    data = text.replace("\n", newline).encode("utf-8", "surrogateescape")
    try:
        parse_gcode(data, path="fuzz.gcode")
    except PrintabilityError as exc:
        _check(exc)


@FUZZ
@given(GCODE)
def test_stream_reader_takes_anything(text):
    try:
        program = parse_program(text.encode(), source="fuzz.gcode", max_line_length=None)
    except PrintabilityError as exc:
        _check(exc)
    else:
        assert all(c == c.strip() and c for c in program.commands)


ATTR_NUMBERS = st.lists(NUMBERS, min_size=1, max_size=8).map(" ".join)
PATH_DATA = st.lists(st.tuples(st.sampled_from(list("MmLlHhVvCcSsQqTtAaZz")), ATTR_NUMBERS),
                     min_size=1, max_size=6).map(lambda cs: " ".join(c + " " + n for c, n in cs))


def _element(draw: st.DrawFn, depth: int, ids: list[str]) -> str:
    kind = draw(st.sampled_from(["path", "rect", "circle", "ellipse", "polygon", "g", "use"]
                                if depth < 3 else ["path", "rect", "circle", "use"]))
    ident = draw(st.sampled_from(["a", "b", "c", ""]))
    attrs = f' id="{ident}"' if ident else ""
    if draw(st.booleans()):
        attrs += f' transform="{draw(st.sampled_from(["scale", "translate", "rotate", "matrix"]))}'\
                 f'({draw(ATTR_NUMBERS)})"'
    if draw(st.booleans()):
        attrs += f' fill="{draw(st.sampled_from(["none", "red", "#000", "url(#a)", ""]))}"'
    if kind == "path":
        return f'<path{attrs} d="{draw(PATH_DATA)}"/>'
    if kind == "polygon":
        return f'<polygon{attrs} points="{draw(ATTR_NUMBERS)}"/>'
    if kind in ("rect", "circle", "ellipse"):
        names = {"rect": ("x", "y", "width", "height"), "circle": ("cx", "cy", "r"),
                 "ellipse": ("cx", "cy", "rx", "ry")}[kind]
        values = " ".join(f'{n}="{draw(NUMBERS)}"' for n in names)
        return f"<{kind}{attrs} {values}/>"
    if kind == "use":
        return f'<use{attrs} xlink:href="#{draw(st.sampled_from(["a", "b", "c", "zz"]))}"/>'
    children = draw(st.lists(st.integers(0, 0), max_size=4))
    return f"<g{attrs}>" + "".join(_element(draw, depth + 1, ids) for _ in children) + "</g>"


@st.composite
def svg_documents(draw: st.DrawFn) -> str:
    size = draw(st.sampled_from(['width="10mm" height="10mm" ', 'width="1e309mm" ', "",
                                 'width="0" height="-5in" ', 'width="nanmm" ']))
    box = draw(st.one_of(st.just("0 0 10 10"), ATTR_NUMBERS))
    body = "".join(_element(draw, 0, []) for _ in range(draw(st.integers(1, 5))))
    return ('<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink" '
            f'{size}viewBox="{box}">{body}</svg>')


@FUZZ
@given(svg_documents())
def test_svg_reader_takes_anything(tmp_path_factory, doc):
    path = tmp_path_factory.mktemp("svg") / "fuzz.svg"
    path.write_text(doc, encoding="utf-8", errors="surrogateescape")
    try:
        load_svg_layers(path)
    except PrintabilityError as exc:
        _check(exc)


@pytest.mark.slow
@settings(max_examples=1500, suppress_health_check=[HealthCheck.too_slow], deadline=None)
@given(svg_documents())
def test_svg_reader_takes_anything_many(tmp_path_factory, doc):
    test_svg_reader_takes_anything.hypothesis.inner_test(tmp_path_factory, doc)


@pytest.mark.slow
@settings(max_examples=1500, deadline=None)
@given(GCODE)
def test_gcode_readers_take_anything_many(text):
    test_gcode_reader_takes_anything.hypothesis.inner_test(text, "\n")
    test_stream_reader_takes_anything.hypothesis.inner_test(text)


# ---------------------------------------------------------------- drawings, maps, meshes

PAIR = st.tuples(NUMBERS, NUMBERS).map(" ".join)
RING = st.lists(PAIR, min_size=0, max_size=8).map(", ".join)
WKT_TEXT = st.lists(st.tuples(st.sampled_from(["POLYGON", "MULTIPOLYGON", "LINESTRING",
                                                "POINT", "polygon", "GEOMETRYCOLLECTION", ""]),
                              st.lists(RING, min_size=1, max_size=3),
                              st.sampled_from(["(", "((", "((("])).map(
    lambda t: f"{t[0]} {t[2]}" + "), (".join(t[1]) + ")" * len(t[2])),
    min_size=1, max_size=3).map("\n".join)

JSON_NUMBER = st.one_of(st.floats(-1e4, 1e4, allow_nan=False).map(repr),
                        st.sampled_from(["NaN", "Infinity", "-Infinity", "1e308", "1e309",
                                         "-0", "1e-320", "9" * 400, '"5"', "null", "true"]))
POSITION = st.lists(JSON_NUMBER, min_size=0, max_size=3).map(lambda v: "[" + ",".join(v) + "]")
LINEAR_RING = st.lists(POSITION, min_size=0, max_size=6).map(lambda v: "[" + ",".join(v) + "]")
POLYGON_COORDS = st.lists(LINEAR_RING, min_size=0, max_size=3).map(
    lambda v: "[" + ",".join(v) + "]")


@st.composite
def geojson_documents(draw: st.DrawFn) -> str:
    kind = draw(st.sampled_from(["Polygon", "MultiPolygon", "Point", "LineString", "Nothing"]))
    coords = draw(POLYGON_COORDS)
    if kind == "MultiPolygon":
        coords = "[" + coords + "]"
    geometry = f'{{"type": "{kind}", "coordinates": {coords}}}'
    wrap = draw(st.sampled_from(["geometry", "feature", "collection", "list"]))
    if wrap == "feature":
        return f'{{"type": "Feature", "properties": {{}}, "geometry": {geometry}}}'
    if wrap == "collection":
        return (f'{{"type": "FeatureCollection", "features": [{{"type": "Feature", '
                f'"geometry": {geometry}}}]}}')
    return geometry if wrap == "geometry" else f"[{geometry}]"


SLICE_TEXT = st.lists(st.one_of(PAIR, NUMBERS, JUNK), min_size=1, max_size=30).map("\n".join)


def _load(tmp_path_factory, name: str, data: bytes, loader) -> None:
    path = tmp_path_factory.mktemp("in") / name
    path.write_bytes(data)
    try:
        loader(path)
    except PrintabilityError as exc:
        _check(exc)


@FUZZ
@given(WKT_TEXT)
def test_wkt_reader_takes_anything(tmp_path_factory, text):
    _load(tmp_path_factory, "fuzz.wkt", text.encode(), load_wkt_layers)


@FUZZ
@given(geojson_documents())
def test_geojson_reader_takes_anything(tmp_path_factory, doc):
    def load(path):
        return load_geojson_layers(path, fit=50.0)

    _load(tmp_path_factory, "fuzz.geojson", doc.encode(), load)


@FUZZ
@given(st.tuples(NUMBERS, NUMBERS), SLICE_TEXT)
def test_slice_reader_takes_anything(tmp_path_factory, widths, text):
    data = f"{widths[0]}\n{widths[1]}\n{text}\n".encode("utf-8", "surrogateescape")
    _load(tmp_path_factory, "fuzz_outline.txt", data, load_slice_layers)


FLOAT32 = st.one_of(st.floats(-100, 100, width=32),
                    st.sampled_from([float("nan"), float("inf"), -float("inf"), 3e38, -1.8e20,
                                     1e16, 0.0]))


@FUZZ
@given(st.lists(st.tuples(*[FLOAT32] * 9), min_size=0, max_size=12),
       st.integers(-2, 2))
def test_binary_stl_reader_takes_anything(tmp_path_factory, triangles, count_error):
    import numpy as np

    rec = np.zeros(len(triangles), dtype=[("normal", "<f4", 3), ("v", "<f4", 9),
                                          ("attr", "<u2")])
    if triangles:
        rec["v"] = np.array(triangles, np.float32)
    count = max(0, len(triangles) + count_error)
    data = b"\0" * 80 + np.uint32(count).tobytes() + rec.tobytes()
    _load(tmp_path_factory, "fuzz.stl", data, load_mesh)


SPEC_VALUE = st.one_of(NUMBERS, st.sampled_from(["", "x", "0 0;1 0;1 1", "1e-9", "-5"]))
NOZZLE_PART = st.tuples(st.sampled_from(["circle", "ellipse", "rect", "polygon", "cone", ""]),
                        st.lists(st.tuples(st.sampled_from(["d", "major", "minor", "w", "h",
                                                            "angle", "x", "y", "pts", "zz"]),
                                           SPEC_VALUE).map("=".join), max_size=4)).map(
    lambda t: t[0] + ":" + ",".join(t[1]))
NOZZLE_SPEC = st.lists(NOZZLE_PART, min_size=1, max_size=3).map("+".join)
MACHINE_SPEC = st.tuples(st.sampled_from(["ttr", "xy", "polar", "scara", "ttr-klipper", "5ax"]),
                         st.lists(st.tuples(st.sampled_from(["min", "max", "step", "speed",
                                                             "full_turn", "zz"]),
                                            SPEC_VALUE).map("=".join), max_size=4)).map(
    lambda t: t[0] + (":" + ",".join(t[1]) if t[1] else ""))


@FUZZ
@given(NOZZLE_SPEC, MACHINE_SPEC)
def test_nozzle_and_machine_specs_take_anything(nozzle, machine):
    for parse, spec in ((parse_nozzle, nozzle), (parse_machine, machine)):
        try:
            parse(spec)
        except PrintabilityError as exc:
            _check(exc)

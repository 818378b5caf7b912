"""Hypothesis strategies for G-code and SVG, through the readers in this process (issue #24,
item 5): whatever the input, a reader returns or raises a
:class:`~printability.errors.PrintabilityError` whose message is one short paragraph."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gcode import parse_gcode
from machine_io import parse_program
from printability.errors import PrintabilityError
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

FUZZ = settings(max_examples=60, suppress_health_check=[HealthCheck.too_slow], deadline=None)


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

"""The post-processor's fast paths give exactly what the lossless slow paths give.

``edit_line`` edits lines of the common slicer shape by slicing bytes and
``simple_move_words`` reads their words without the tokeniser; both must agree
with :func:`gcode.line.parse_line` (and ``edit_line``'s token-based path) on
every G0/G1 line of the real sample files and on odd generated lines. The
rewrite's per-chord E scale and planned turn, computed for all chords at once,
must be the same bits as the scalar helpers.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from gcode_samples import GCODE_SAMPLES
from hypothesis import given, settings
from hypothesis import strategies as st

from gcode.edit import edit_tokens as _edit_tokens
from gcode.line import parse_line
from gcode.rotary import bead_area
from gcode.writer import edit_line, simple_move_words
from printability.model.nozzle import parse_nozzle
from printability.postprocess.rewrite import e_scale, e_scales, planned_turns

SAMPLES = GCODE_SAMPLES

# the edits the rewrite makes: a rotary word, a new E, both (E is added where it is missing)
EDITS = [
    ({}, ["C12.5"]),
    ({"E": "E0.01234"}, []),
    ({"E": "E-1.5"}, ["C-270.125"]),
]


def _check_line(raw: bytes) -> bool:
    """Assert fast == slow for one line; True when the fast path took it."""
    parsed = parse_line(raw)
    words = simple_move_words(raw)
    if words is not None:
        assert words == [w.text for w in parsed.words], raw
        assert parsed.kind == "command" and parsed.bad_column is None, raw
    for replace, add in EDITS:
        assert edit_line(raw, replace=replace, add=add) == \
            _edit_tokens(parsed, replace=replace, add=add), (raw, replace, add)
    return words is not None


@pytest.mark.parametrize("name", SAMPLES)
def test_fast_path_matches_tokeniser_on_samples(shared_data, name):
    data = (shared_data / "gcode" / name).read_bytes()
    n = fast = 0
    for raw in data.splitlines(keepends=True):
        if raw.lstrip(b" \t")[:2].upper() not in (b"G0", b"G1"):
            continue
        n += 1
        fast += _check_line(raw)
    assert n > 1000
    # the point of the fast path: slicers' moves take it
    assert fast > 0.9 * n, (fast, n)


def test_fast_path_shapes():
    assert simple_move_words(b"G1 X1.5 Y-2 E.03 F1800 ; perimeter\n") == \
        [b"X1.5", b"Y-2", b"E.03", b"F1800"]
    assert simple_move_words(b"G1 Z.2\r\n") == [b"Z.2"]
    assert simple_move_words(b"G0;travel") == []
    # everything else goes through the tokeniser
    for raw in [b"g1 X1\n", b"N3 G1 X1*99\n", b"G1 X1.\n", b"G1\tX1\n", b"G1 X1E2\n",
                b" G1 X1\n", b"G1 x1\n", b"G1 X\n", b"M104 S200\n", b"G1 X1 ;a\rb\n"]:
        assert simple_move_words(raw) is None, raw
    raw = b"G1  X1   E2.5 \t; keep  this\r\n"
    assert edit_line(raw, replace={"E": "E0.5"}, add=["C90"]) == \
        b"G1  X1   E0.5 C90 \t; keep  this\r\n"
    assert edit_line(raw, replace={"E": "E0.5"}, add=["C90"]) == \
        _edit_tokens(parse_line(raw), replace={"E": "E0.5"}, add=["C90"])


_numbers = st.one_of(
    st.from_regex(r"\A[-+]?([0-9]{1,4}(\.[0-9]{0,5})?|\.[0-9]{1,5})\Z", fullmatch=True),
    st.sampled_from(["", "1.", "1.2.3", "1e3", "--1", "+", ".", "0x1", "-0", '"a b"', "1*"]),
)
_word = st.tuples(st.sampled_from(list("XYZEFCIJxyzeNG*;")), _numbers).map("".join)
_blank = st.sampled_from([" ", " ", " ", "  ", "\t", "", " \t"])


@st.composite
def _odd_lines(draw) -> bytes:
    lead = draw(st.sampled_from(["", "", "", " ", "\ufeff", "N12 "]))
    cmd = draw(st.sampled_from(["G1", "G1", "G0", "G01", "g1", "G1.5", "G", "M104", "G28"]))
    words = draw(st.lists(st.tuples(_blank, _word), max_size=6))
    tail = draw(_blank)
    comment = draw(st.one_of(st.just(""), st.sampled_from([";", "; c", ";x\x00\xff\r", ";é"])))
    eol = draw(st.sampled_from(["\n", "\n", "\r\n", "\r", ""]))
    text = lead + cmd + "".join(b + w for b, w in words) + tail + comment
    return text.encode("utf-8") + eol.encode()


@settings(max_examples=800)
@given(_odd_lines())
def test_fast_path_matches_tokeniser_on_odd_lines(raw):
    _check_line(raw)


@settings(max_examples=300)
@given(st.binary(max_size=40).map(lambda b: b.replace(b"\n", b" ").replace(b"\r", b" ")),
       st.sampled_from([b"", b"\n", b"\r\n"]))
def test_fast_path_matches_tokeniser_on_random_bytes(body, eol):
    _check_line(b"G1 " + body + eol)
    _check_line(body + eol)


_width = st.one_of(st.floats(0.0, 2.0), st.just(math.nan), st.just(math.inf),
                   st.just(0.45))


@settings(max_examples=200)
@given(st.lists(st.tuples(_width, _width, st.sampled_from([0.05, 0.2, 0.3, 0.75])),
                min_size=1, max_size=20),
       st.sampled_from(["width", "keep"]))
def test_vector_e_scale_is_the_scalar_one(rows, e_policy):
    nozzle = parse_nozzle("ellipse:major=0.8,minor=0.3")
    wl, wp, h = (np.array(c, dtype=float) for c in zip(*rows, strict=True))
    got = e_scales(wl, wp, h, e_policy, nozzle, bead_area)
    want = [e_scale(a, b, float(c), e_policy, nozzle, bead_area) for a, b, c in rows]
    assert got.tolist() == want


@given(st.lists(st.one_of(st.floats(-720, 720), st.just(math.nan)), max_size=20))
def test_vector_planned_turn(angles):
    a = np.array(angles, dtype=float)
    want = [-1.0 if s == 0 or not (math.isfinite(a[s]) and math.isfinite(a[s - 1]))
            else abs(float(a[s] - a[s - 1])) for s in range(len(a))]
    assert planned_turns(a).tolist() == want


# ---- the compiled rewrite pass's line shape (gcode.text_kernels) against the Python it
# replaces


def _span(raw: bytes) -> tuple[int, int]:
    from gcode.edit import SIMPLE_MOVE as _SIMPLE_MOVE

    m = _SIMPLE_MOVE.match(raw)
    return m.span(1) if m is not None else (-1, -1)


@settings(max_examples=800)
@given(_odd_lines())
def test_compiled_line_shape_is_the_expression(raw):
    from gcode.text_kernels import simple_span

    assert simple_span(np.frombuffer(raw, np.uint8), 0, len(raw)) == _span(raw), raw


@settings(max_examples=300)
@given(st.binary(max_size=40).map(lambda b: b.replace(b"\n", b" ").replace(b"\r", b" ")),
       st.sampled_from([b"", b"\n", b"\r\n", b"\r"]))
def test_compiled_line_shape_on_random_bytes(body, eol):
    from gcode.text_kernels import simple_span

    for raw in (b"G1 " + body + eol, body + eol, b"G1 X1 " + body[:3] + eol):
        assert simple_span(np.frombuffer(raw, np.uint8), 0, len(raw)) == _span(raw), raw

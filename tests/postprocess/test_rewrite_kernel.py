"""The compiled rewrite pass writes the bytes of the Python reference.

Oracles: :func:`gcode.writer.format_number` (printf's correctly rounded digits)
for the compiled number formatting (:mod:`gcode.text_kernels`), ``float()`` for its
number reading, :func:`printability.postprocess.rewrite.rewrite_reference` for the whole
pass, on real slicer files under every option that changes what is written (bounded axis,
unwind, feed policy, absolute E, spiral vase climbs, an offset orifice).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pp_helpers import first_layers

import gcode.text_kernels as tk
import printability.postprocess._rewrite_kernel as rk
from gcode.writer import format_number
from printability.postprocess import PostprocessOptions, postprocess_bytes


def _formatted(v: float, d: int) -> bytes | None:
    buf = np.zeros(64, np.uint8)
    n = tk.put_fixed(buf, 0, v, d)
    return None if n < 0 else buf[:n].tobytes()


@settings(max_examples=3000)
@given(st.one_of(st.floats(allow_nan=False, allow_infinity=False, width=64),
                 st.floats(-1e6, 1e6), st.floats(-2.0, 2.0),
                 st.integers(-10**9, 10**9).map(lambda k: k / 2**11)),  # exact ties
       st.integers(0, 8))
@example(0.0005, 3)  # just above the tie in binary: rounds up
@example(0.125, 2)  # an exact tie: to even
@example(-0.0004, 3)  # "-0" is written "0"
@example(2.675, 2)  # just below the tie in binary
@example(-0.0, 5)
def test_compiled_format_is_printf(v, d):
    got = _formatted(v, d)
    if abs(v) * 10.0 ** d < 1e15:
        assert got == format_number(v, d).encode(), (v, d)
    else:
        assert got is None or got == format_number(v, d).encode()


def test_compiled_format_declines_what_it_cannot_round():
    assert _formatted(math.nan, 3) is None
    assert _formatted(math.inf, 3) is None
    assert _formatted(1e12, 5) is None  # 1e17 is past the exact fractions
    assert _formatted(123456.789, 5) == b"123456.789"


_texts = st.one_of(
    st.from_regex(r"\A[-+]?([0-9]{1,9}(\.[0-9]{0,9})?|\.[0-9]{1,12})\Z", fullmatch=True),
    st.floats(-1e5, 1e5).map(repr).filter(lambda t: "e" not in t),
    st.sampled_from(["0", "-0", "+.5", "000.000100", "1" * 15, "9" * 15 + ".", ".0000001"]),
)


@settings(max_examples=1000)
@given(_texts)
def test_compiled_number_reading_is_float(text):
    raw = text.encode()
    ok, value = tk.parse_number(np.frombuffer(raw, np.uint8), 0, len(raw))
    digits = len(text.lstrip("+-").replace(".", "").lstrip("0"))
    if digits <= 15:
        assert ok
    if ok:
        assert value == float(text) and math.copysign(1, value) == math.copysign(1, float(text))


def test_compiled_number_reading_declines():
    for text in (b"", b"-", b".", b"1.2.3", b"1e3", b"1234567890123456", b"0x1"):
        ok, _ = tk.parse_number(np.frombuffer(text, np.uint8), 0, len(text))
        assert not ok, text


def _both(data: bytes, **kw) -> tuple[bytes, bytes, list[int]]:
    """The post-processed file through the compiled pass and through the reference (the
    compiled pass declining every file)."""
    statuses = []
    kernel = rk.rewrite_kernel

    def spy(*a):
        r = kernel(*a)
        statuses.append(int(r[0]))
        return r

    opts = PostprocessOptions(**kw)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(rk, "rewrite_kernel", spy)
        fast, res_fast = postprocess_bytes(data, options=opts)
        mp.setattr(rk, "rewrite_compiled", lambda *a: None)
        slow, res_slow = postprocess_bytes(data, options=opts)
    assert (res_fast.changed_lines, res_fast.inserted_lines, res_fast.rotary_words) == \
        (res_slow.changed_lines, res_slow.inserted_lines, res_slow.rotary_words)
    assert [r.turned for r in res_fast.layers] == [r.turned for r in res_slow.layers]
    return fast, slow, statuses


ELLIPSE = "ellipse:major=0.8,minor=0.3"
OPTIONS = [
    {"nozzle": ELLIPSE, "machine": "ttr"},
    {"nozzle": "rect:w=0.7,h=0.35", "machine": "ttr"},
    {"nozzle": ELLIPSE, "machine": "ttr:min=-90,max=90"},
    {"nozzle": ELLIPSE, "machine": "ttr:min=-90,max=90", "unwind": True},
    {"nozzle": ELLIPSE, "machine": "ttr", "feed_policy": "euclidean"},
    {"nozzle": ELLIPSE, "machine": "xy"},
    {"nozzle": "ellipse:major=0.8,minor=0.3,x=0.05", "machine": "ttr"},
]


@pytest.mark.parametrize("opts", OPTIONS, ids=lambda o: ",".join(map(str, o.values())))
@pytest.mark.parametrize("fixture", ["prusa_short", "benchy_short"])
def test_compiled_rewrite_is_the_reference(request, fixture, opts):
    data = request.getfixturevalue(fixture).read_bytes()
    fast, slow, statuses = _both(data, **opts)
    assert statuses == [rk.OK]
    assert fast == slow


@pytest.mark.parametrize("name", ["prusaslicer_2.7.4_spiral_vase.gcode",
                                  "cura_5.9.1_marlin.gcode"])
def test_compiled_rewrite_on_climbs_and_absolute_e(shared_data, name):
    data = first_layers(shared_data / "gcode" / name, 8)
    if name.startswith("cura"):
        data = first_layers(shared_data / "gcode" / name, 4, marker=b";LAYER:")
    fast, slow, statuses = _both(data, nozzle=ELLIPSE, machine="ttr")
    assert statuses == [rk.OK]
    assert fast == slow


def test_a_line_the_kernel_cannot_edit_goes_to_the_reference(prusa_short):
    data = prusa_short.read_bytes()
    # an extruding move written with a tab: not the common shape, so the tokeniser edits it
    i = data.index(b"\nG1 X", data.index(b";TYPE:External perimeter")) + 1
    j = data.index(b"\n", i)
    line = data[i:j]
    assert b" E" in line
    odd = data[:i] + line.replace(b"G1 ", b"G1\t", 1) + data[j:]
    fast, slow, statuses = _both(odd, nozzle=ELLIPSE, machine="ttr")
    assert statuses == [rk.DECLINED]
    assert fast == slow


def test_long_words_stay_inside_the_kernels_buffers(prusa_short):
    """Moves whose F word is long (a split move's first new line copies it): the compiled
    pass writes what the reference writes (its buffers grow to fit)."""
    data = prusa_short.read_bytes()
    long_f = b" F1800." + b"0" * 3000  # long, and a feed a printer takes (1800 mm/min)
    lines = data.split(b"\n")
    for k, line in enumerate(lines):
        if line.startswith(b"G1 X") and b" E" in line and b";" not in line:
            lines[k] = line + long_f
    fast, slow, statuses = _both(b"\n".join(lines), nozzle=ELLIPSE, machine="ttr")
    assert statuses == [rk.OK]
    assert fast == slow
    assert long_f in fast

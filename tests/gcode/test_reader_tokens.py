"""Tokeniser: byte-for-byte round trip and agreement of the two independent tokenisers."""

from __future__ import annotations

import json

import hypothesis.strategies as st
import numpy as np
import pytest
from _gcode_reader_compare import mismatches, tables_equal
from gcode_samples import GCODE_SAMPLES
from hypothesis import given, settings

from gcode import _lexer, parse_gcode, parse_line, read_gcode
from gcode._lexer import lex

SAMPLES = GCODE_SAMPLES


@pytest.fixture(scope="module", params=SAMPLES)
def sample(request, shared_data):
    path = shared_data / "gcode" / request.param
    return path, path.read_bytes()


# Every line of every sample through the pure-Python tokeniser takes ~20 s:
# the default run checks every 7th line, the slow run all of them.
STEPS = [7, pytest.param(1, marks=pytest.mark.slow)]


@pytest.mark.parametrize("step", STEPS)
def test_sample_round_trips_byte_for_byte(sample, step):
    path, data = sample
    g = read_gcode(path)
    assert g.to_bytes() == data
    assert b"".join(g.iter_lines()) == data
    assert len(g) == len(data.splitlines())
    # lines through the token stream, too
    raws = list(g.iter_lines())[::step]
    assert [parse_line(raw).to_bytes() for raw in raws] == raws


@pytest.mark.parametrize("step", STEPS)
def test_sample_tables_agree_with_line_tokeniser(sample, step):
    _, data = sample
    lines, words = lex(data)
    assert mismatches(data, lines, words, step=step) == []


def test_numba_and_interpreted_kernel_agree(sample):
    _, data = sample
    head = b"".join(data.splitlines(keepends=True)[:2000])
    assert tables_equal(lex(head, engine="numba"), lex(head, engine="python"))


CASES = [
    (b"G1 X1.5 Y-2 E.5 F3000\n", "command", "G", 1, None, [("X", 1.5), ("Y", -2.0), ("E", 0.5),
                                                           ("F", 3000.0)]),
    (b"M84 X Y E\n", "command", "M", 84, None, [("X", None), ("Y", None), ("E", None)]),
    (b"M862.3 P \"MK3S\" ; printer model\n", "command", "M", 862, 3, [("P", None), ("", None)]),
    (b"T0\n", "command", "T", 0, None, []),
    (b"g1 x10 y-3.25 e1.\r\n", "command", "G", 1, None, [("X", 10.0), ("Y", -3.25), ("E", 1.0)]),
    (b"G1X10Y20Z.3\n", "command", "G", 1, None, [("X", 10.0), ("Y", 20.0), ("Z", 0.3)]),
    (b"EXCLUDE_OBJECT_DEFINE NAME=a_b CENTER=150,150 POLYGON=[[1,2],[3,4]]\n", "extended", "E",
     None, None, []),
    (b"SET_VELOCITY_LIMIT ACCEL=1000 ACCEL_TO_DECEL=1000\n", "extended", "S", None, None, []),
    (b"M117 Printing; 50%\n", "command", "M", 117, None, []),
    (b"   \t\n", "blank", None, None, None, []),
    (b";LAYER:3\n", "comment", None, None, None, []),
    (b"X12 Y5\n", "words", None, None, None, [("X", 12.0), ("Y", 5.0)]),
    (b"G1 X1 ; \xff\xfe not utf-8\n", "command", "G", 1, None, [("X", 1.0)]),
    (b"G3 Z.8 I.044 J-1.216 P1  F30000\n", "command", "G", 3, None,
     [("Z", 0.8), ("I", 0.044), ("J", -1.216), ("P", 1.0), ("F", 30000.0)]),
    (b"G1 X1", "command", "G", 1, None, [("X", 1.0)]),
    (b"\xef\xbb\xbfG1 X2\n", "command", "G", 1, None, [("X", 2.0)]),  # UTF-8 BOM
    (b"G1 X1\r", "command", "G", 1, None, [("X", 1.0)]),
]


@pytest.mark.parametrize(("raw", "kind", "letter", "major", "minor", "words"), CASES)
def test_line_cases(raw, kind, letter, major, minor, words):
    p = parse_line(raw)
    assert p.to_bytes() == raw
    assert (p.kind, p.letter, p.major, p.minor) == (kind, letter, major, minor)
    assert [(w.letter, w.value) for w in p.words] == words
    lines, lwords = lex(raw)
    assert mismatches(raw, lines, lwords) == []


def _checksum(body: bytes) -> int:
    x = 0
    for b in body:
        x ^= b
    return x


def test_line_number_and_checksum():
    body = b"N123 G1 X10.5 Y-3"
    raw = body + b"*%d\n" % _checksum(body)
    p = parse_line(raw)
    assert p.line_number == 123 and p.checksum == _checksum(body) and p.checksum_ok
    assert [s.kind for s in p.segments] == ["number", "ws", "command", "ws", "word", "ws", "word",
                                            "checksum", "eol"]
    lines, _ = lex(raw)
    assert lines["checksum_ok"][0] and lines["line_number"][0] == 123
    bad = body + b"*%d\n" % ((_checksum(body) + 1) % 256)
    assert not parse_line(bad).checksum_ok
    assert not lex(bad)[0]["checksum_ok"][0]


def test_line_endings_and_missing_final_newline():
    data = b"G1 X1\r\nG1 X2\rG1 X3\n\nG1 X4"
    g = parse_gcode(data)
    assert [g.line(i) for i in range(len(g))] == [b"G1 X1\r\n", b"G1 X2\r", b"G1 X3\n", b"\n",
                                                  b"G1 X4"]
    assert g.to_bytes() == data
    assert g.moves["x1"].tolist() == [1, 2, 3, 4]


# Random lines over an alphabet that exercises every branch of the grammar.
_ALPHABET = [*b"GMTNXYZEFIJRPgxyz0123456789.-+ \t;*\"=_[],", 0xFF, 0xC3, 0xA9, 0xEF, 0xBB,
             0xBF]
_line = st.lists(st.sampled_from(_ALPHABET), max_size=40).map(bytes)
_eol = st.sampled_from([b"\n", b"\r\n", b""])


@settings(max_examples=300, deadline=None)
@given(_line, _eol)
def test_random_lines_round_trip_and_tokenisers_agree(body, eol):
    raw = body + eol
    p = parse_line(raw)
    assert p.to_bytes() == raw
    for w in p.words:
        if w.value is not None:
            assert float(w.text[1:]) == w.value
    lines, words = lex(raw)
    assert mismatches(raw, lines, words) == []
    assert tables_equal((lines, words), lex(raw, engine="python"))


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(_line, st.sampled_from([b"\n", b"\r\n", b"\r"])), max_size=12))
def test_random_files_round_trip(rows):
    data = b"".join(a + b for a, b in rows)
    lines, words = lex(data)
    assert len(lines["kind"]) == len(data.splitlines())
    assert mismatches(data, lines, words) == []


def test_numbers_convert_exactly():
    texts = [b"0.1", b"-0", b"123456789.123456789", b".000000000000000000000001", b"1.",
             b"99999999999999999999", b"0.30000000000000004"]
    data = b"".join(b"G1 X" + t + b"\n" for t in texts)
    _, words = lex(data)
    assert words["value"].tolist() == [float(t) for t in texts]
    assert np.signbit(words["value"][1])
    assert not (words["flags"] & _lexer.WORD_INEXACT).any()


def test_extended_params(shared_data):
    from gcode import extended_params

    assert extended_params(b'SET_VELOCITY_LIMIT ACCEL=1000 ACCEL_TO_DECEL=500 ; x\n') == {
        "ACCEL": "1000", "ACCEL_TO_DECEL": "500"}
    assert extended_params(b'RESPOND MSG="a b" TYPE=echo\n') == {"MSG": '"a b"', "TYPE": "echo"}
    assert extended_params(b'M117 ignored WORD=x[1, 2] Y=2\r\n') == {"WORD": "x[1, 2]", "Y": "2"}
    data = (shared_data / "gcode" / "bambustudio_1.10_klipper_arcs.gcode").read_bytes()
    line = next(x for x in data.splitlines() if x.startswith(b"EXCLUDE_OBJECT_DEFINE"))
    p = extended_params(line)
    assert p["NAME"] == "TC_Top.stl_id_0_copy_0" and p["CENTER"] == "150,150"
    pts = json.loads(p["POLYGON"])
    assert len(pts) > 100 and all(len(q) == 2 for q in pts)

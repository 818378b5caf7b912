"""Binary G-code in, binary G-code out: postprocess_bytes / postprocess_file on .bgcode."""

from __future__ import annotations

import pytest
from bg_helpers import (
    CONFIG_IDS,
    CONFIGS,
    PRUSA_DEFAULT,
    binarize,
    commands,
    library_gcode,
    library_valid,
    with_thumbnails,
)
from gcode_samples import GCODE_SAMPLES

from gcode import parse_gcode, read_gcode
from gcode.bgcode import PRINT_METADATA, PRINTER_METADATA, decode_bgcode
from printability.base.errors import FileFormatError
from printability.postprocess import (
    PROCESSED_KEY,
    PostprocessOptions,
    already_processed,
    postprocess_bytes,
    postprocess_file,
)

ELLIPSE = PostprocessOptions(nozzle="ellipse:major=0.8,minor=0.3", machine="ttr")
# one mode per compression in the default run, every encoding among them; the rest is slow
QUICK = [(0, 0), (1, 1), (2, 2), (3, 2)]
MODES = [pytest.param(c, e, id=i, marks=() if (c, e) in QUICK else pytest.mark.slow)
         for (c, e), i in zip(CONFIGS, CONFIG_IDS, strict=True)]


def _text_path(doc, options=ELLIPSE) -> bytes:
    """What the text path makes of the binary file's text form: its G-code part."""
    trailer = doc.trailer()
    out, _ = postprocess_bytes(doc.gcode + trailer, options=options)
    assert out.endswith(trailer)
    return out[:len(out) - len(trailer)]


def _kept_blocks(before: bytes, after: bytes) -> None:
    """Every block but the G-code and the print/printer metadata is the same bytes."""
    a, b = decode_bgcode(before), decode_bgcode(after)
    skip = (1, PRINT_METADATA, PRINTER_METADATA)
    assert [before[k.start:k.end] for k in a.blocks if k.type not in skip] == \
        [after[k.start:k.end] for k in b.blocks if k.type not in skip]


def _check_binary_against_text(data: bytes, text: bytes | None, compression: int,
                               encoding: int, options=ELLIPSE) -> bytes:
    """Post-process ``data`` (binary): the result is binary G-code of the same compression
    and encoding that libbgcode validates; its G-code is what the text path makes of the
    same input (without MeatPack to the byte; with it, as libbgcode encodes that text); its
    commands are those the text path makes of the slicer's text ``text`` (when given, and
    the encoding keeps the comments the plan reads); metadata and thumbnails kept."""
    new, res = postprocess_bytes(data, path="part.bgcode", options=options)
    assert new[:4] == b"GCDE" and library_valid(new)
    assert res.binary and not res.already_processed and res.rotary_words > 0
    doc, out = decode_bgcode(data), decode_bgcode(new)
    assert {(b.compression, b.encoding) for b in out.gcode_blocks} == {(compression, encoding)}
    expect = _text_path(doc, options)
    if encoding:
        expect = library_gcode(binarize(expect, compression, encoding))
    assert out.gcode == expect == library_gcode(new)
    if text is not None and encoding != 1:
        reference, _ = postprocess_bytes(text, options=options)
        assert commands(out.gcode) == commands(reference)
    _kept_blocks(data, new)
    assert res.lines_in == doc.gcode.count(b"\n")
    assert already_processed(new)
    return new


@pytest.mark.parametrize(("compression", "encoding"), MODES)
def test_postprocessed_binary_is_the_text_paths_output(sample_text, sample_binary, compression,
                                                      encoding):
    data = sample_binary("short", compression, encoding)
    _check_binary_against_text(data, with_thumbnails(sample_text("short")), compression,
                               encoding)


@pytest.mark.slow
@pytest.mark.parametrize("name", GCODE_SAMPLES)
@pytest.mark.parametrize(("compression", "encoding"), [(0, 0), PRUSA_DEFAULT, (1, 1)])
def test_every_sample_goes_through_binary(sample_text, sample_binary, name, compression,
                                         encoding):
    prusa = name.startswith("prusaslicer")
    _check_binary_against_text(sample_binary(name, compression, encoding),
                               sample_text(name) if prusa else None, compression, encoding)


def test_print_metadata_follow_the_new_gcode(sample_binary):
    """The estimated times scale with the planner's ratio, the filament used with the
    filament the extrusions push; the first-layer time and the wipe tower stay."""
    data = sample_binary("short", *PRUSA_DEFAULT)
    new, res = postprocess_bytes(data, options=ELLIPSE)
    before, after = decode_bgcode(data), decode_bgcode(new)
    t_ratio = res.print_time_out / res.print_time_in
    e_ratio = res.filament_out / res.filament_in
    assert t_ratio > 1.01 and e_ratio != 1.0

    def seconds(v: str) -> int:
        m, s = v.split()
        return int(m[:-1]) * 60 + int(s[:-1])

    for kind in (PRINT_METADATA, PRINTER_METADATA):
        key = "estimated printing time (normal mode)"
        assert seconds(after.value(key, kind)) == round(seconds(before.value(key, kind))
                                                        * t_ratio)
        mm = float(after.value("filament used [mm]", kind))
        assert mm == pytest.approx(float(before.value("filament used [mm]", kind)) * e_ratio,
                                   abs=0.006)
    for key in ("estimated first layer printing time (normal mode)",
                "total filament used for wipe tower [g]"):
        assert after.value(key) == before.value(key)
    assert any("metadata updated" in n for n in res.notes)


def test_a_round_nozzle_rewrites_only_the_first_block(sample_binary):
    """The slicer's own nozzle (read from the printer metadata): only the comment block goes
    in, so every G-code block but the first is kept byte for byte."""
    data = sample_binary(GCODE_SAMPLES[3], *PRUSA_DEFAULT)
    new, res = postprocess_bytes(data, options=PostprocessOptions(machine="ttr"))
    assert res.nozzle == "circle:d=0.4"
    a, b = decode_bgcode(data), decode_bgcode(new)
    assert len(a.gcode_blocks) > 5
    assert [data[k.start:k.end] for k in a.gcode_blocks[1:]] == \
        [new[k.start:k.end] for k in b.gcode_blocks[-(len(a.gcode_blocks) - 1):]]
    assert b.gcode_texts[0].startswith(a.gcode_texts[0][:200])
    assert b"; printability 0.1" in b.gcode_texts[0]


def test_meatpack_without_comments_marks_the_print_metadata(sample_binary):
    """MeatPack without comments keeps no comment: the marker goes in the print metadata,
    and a second run leaves the file as it is."""
    data = sample_binary("short", 2, 1)
    new, res = postprocess_bytes(data, options=ELLIPSE)
    out = decode_bgcode(new)
    assert b";" not in out.gcode and res.rotary_words > 0
    assert out.value(PROCESSED_KEY).startswith("printability ")
    again, res2 = postprocess_bytes(new, options=ELLIPSE)
    assert res2.already_processed and again == new
    assert already_processed(new) and not already_processed(data)


def test_already_processed_binary_is_left_as_it_is(sample_binary, tmp_path):
    data = sample_binary("short", *PRUSA_DEFAULT)
    f = tmp_path / "part.bgcode"
    f.write_bytes(data)
    res = postprocess_file(f, options=ELLIPSE)
    once = f.read_bytes()
    assert res.binary and once != data
    res2 = postprocess_file(f, options=ELLIPSE)
    assert res2.already_processed and f.read_bytes() == once


def _damage(data: bytes, how: str) -> bytes:
    doc = decode_bgcode(data)
    g = doc.gcode_blocks[-1]
    bad = bytearray(data)
    if how == "crc":
        bad[(g.data + g.end) // 2] ^= 1
    elif how == "truncated":
        return data[:(g.data + g.end) // 2]
    elif how == "compression":
        bad[g.start + 2] = 9
        import struct
        import zlib
        struct.pack_into("<I", bad, g.end - 4, zlib.crc32(bytes(bad[g.start:g.end - 4])))
    return bytes(bad)


@pytest.mark.parametrize("how", ["crc", "truncated", "compression"])
def test_a_damaged_binary_file_is_left_untouched(sample_binary, tmp_path, how):
    bad = _damage(sample_binary("short", *PRUSA_DEFAULT), how)
    f = tmp_path / "part.bgcode"
    f.write_bytes(bad)
    with pytest.raises(FileFormatError) as exc:
        postprocess_file(f, options=ELLIPSE)
    msg = str(exc.value)
    assert msg.startswith(f"{f}: damaged binary G-code (.bgcode):") and "\n" not in msg
    assert "G-code block" in msg
    assert f.read_bytes() == bad
    assert [p.name for p in tmp_path.iterdir()] == ["part.bgcode"]


def test_the_reader_reads_binary_gcode_as_its_text_form(sample_binary, tmp_path):
    """parse_gcode / read_gcode decode binary G-code: the same moves and layers as its text
    form; a damaged one is refused naming the block."""
    data = sample_binary("short", *PRUSA_DEFAULT)
    f = tmp_path / "part.bgcode"
    f.write_bytes(data)
    g = read_gcode(f)
    t = parse_gcode(decode_bgcode(data).text_form())
    assert g.data == t.data and g.flavor == "marlin" and g.slicer == "PrusaSlicer"
    assert g.moves.tobytes() == t.moves.tobytes() and len(g.moves) > 500
    assert g.layers.tobytes() == t.layers.tobytes() and len(g.layers) == 4
    with pytest.raises(FileFormatError, match=r"part\.bgcode: damaged binary G-code .*CRC32"):
        parse_gcode(_damage(data, "crc"), path="part.bgcode")

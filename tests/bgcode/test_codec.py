"""gcode.bgcode against libbgcode: decode, encode, the block framing, damaged files."""

from __future__ import annotations

import struct
import zlib

import pytest
from bg_helpers import (
    CONFIG_IDS,
    CONFIGS,
    PRUSA_DEFAULT,
    library_blocks,
    library_gcode,
    library_valid,
    png,
)
from gcode_samples import GCODE_SAMPLES

from gcode import bgcode
from gcode.bgcode import (
    decode_bgcode,
    encode_bgcode,
    encode_gcode_blocks,
    is_bgcode,
    rescaled_metadata,
)
from printability.base.errors import FileFormatError


@pytest.mark.parametrize("name", GCODE_SAMPLES)
def test_every_sample_round_trips_byte_for_byte(sample_binary, name):
    """Every shared sample in PrusaSlicer's binary form: decoded, its G-code is the library's,
    and encoded back unchanged it is the same bytes; the thumbnails are there."""
    data = sample_binary(name, *PRUSA_DEFAULT)
    doc = decode_bgcode(data, path=name)
    assert is_bgcode(data) and doc.gcode == library_gcode(data)
    assert sum(b.type == bgcode.THUMBNAIL for b in doc.blocks) >= 2
    assert encode_bgcode(doc, doc.gcode) == data


@pytest.mark.parametrize(("compression", "encoding"), CONFIGS, ids=CONFIG_IDS)
def test_every_mode_round_trips_and_reencodes_as_the_library(sample_binary, compression,
                                                             encoding):
    """Each compression with and without MeatPack: the round trip is byte for byte; every
    G-code block encoded again from its text is the library's block to the byte without
    MeatPack, and decodes to the same text with it (MeatPack drops what its decoder puts
    back, so only unchanged blocks can be kept exact: they are not re-encoded)."""
    data = sample_binary(GCODE_SAMPLES[3], compression, encoding)
    doc = decode_bgcode(data)
    assert (doc.compression, doc.encoding) == (compression, encoding)
    assert doc.gcode == library_gcode(data)
    assert encode_bgcode(doc, doc.gcode) == data
    again = encode_gcode_blocks(doc.gcode_texts, compression=compression, encoding=encoding)
    original = [data[b.start:b.end] for b in doc.gcode_blocks]
    if encoding == 0:
        assert again == original
    else:
        texts = [t for k, t in library_blocks(bytes(doc.data[:10]) + b"".join(again)) if k == 1]
        assert [t.encode() for t in texts] == list(doc.gcode_texts)


@pytest.mark.parametrize(("compression", "encoding"), CONFIGS, ids=CONFIG_IDS)
def test_new_gcode_is_encoded_as_the_file_was(sample_binary, compression, encoding):
    """A change in the middle: the blocks before and after are kept byte for byte, the rest
    is re-encoded with the file's compression and encoding, in blocks of at most 64 KiB of
    text; the library validates the file and decodes the new text; every other block is
    kept."""
    data = sample_binary(GCODE_SAMPLES[3], compression, encoding)
    doc = decode_bgcode(data)
    texts = list(doc.gcode_texts)
    k = len(texts) // 2
    lines = texts[k].split(b"\n")
    lines[3] += b"\nG1 X1 Y2 C45.000\n; a new comment line"
    changed = b"".join(texts[:k]) + b"\n".join(lines) + b"".join(texts[k + 1:])
    new = encode_bgcode(doc, changed)
    assert library_valid(new)
    doc2 = decode_bgcode(new)
    expect = changed if encoding == 0 else \
        changed.replace(b"\n; a new comment line", b"" if encoding == 1 else
                        b"\n; a new comment line")
    assert doc2.gcode == expect == library_gcode(new)
    old_blocks = [data[b.start:b.end] for b in doc.blocks]
    new_blocks = [new[b.start:b.end] for b in doc2.blocks]
    gcode_at = doc.gcode_blocks[0].index
    assert new_blocks[:gcode_at] == old_blocks[:gcode_at]  # metadata, thumbnails
    assert new_blocks[gcode_at:gcode_at + k] == old_blocks[gcode_at:gcode_at + k]
    assert new_blocks[-(len(texts) - k - 1):] == old_blocks[-(len(texts) - k - 1):]
    assert all((b.compression, b.encoding) == (compression, encoding)
               for b in doc2.gcode_blocks)
    assert all(len(t) <= 65536 for t in doc2.gcode_texts)


def test_a_kept_block_never_starts_inside_a_line(sample_binary):
    """Text joined to the first line of a block: that block is not kept, every block still
    holds whole lines."""
    data = sample_binary(GCODE_SAMPLES[3], 0, 0)
    doc = decode_bgcode(data)
    texts = doc.gcode_texts
    changed = b"".join(texts[:2]) + b"G1 X1 Y1 ; " + b"".join(texts[2:])
    new = decode_bgcode(encode_bgcode(doc, changed))
    assert new.gcode == changed
    assert all(t.endswith(b"\n") for t in new.gcode_texts)
    kept = [data[b.start:b.end] for b in doc.gcode_blocks]
    assert [new.data[b.start:b.end] for b in new.gcode_blocks[:2]] == kept[:2]
    assert [new.data[b.start:b.end] for b in new.gcode_blocks[-3:]] == kept[-3:]


def test_long_text_goes_in_64_kib_blocks_cut_at_line_ends(sample_binary):
    """libbgcode's rule: whole lines while they fit in 64 KiB."""
    data = sample_binary("short", *PRUSA_DEFAULT)
    doc = decode_bgcode(data)
    big = b"".join(b"G1 X%d Y%d\n" % (i, i) for i in range(30000))
    new = decode_bgcode(encode_bgcode(doc, big))
    sizes = [len(t) for t in new.gcode_texts]
    assert new.gcode == big and len(sizes) > 3
    assert all(65536 - 14 < s <= 65536 for s in sizes[:-1])
    assert all(t.endswith(b"\n") for t in new.gcode_texts)


def test_text_form_ends_with_the_metadata_a_text_file_ends_with(sample_binary):
    doc = decode_bgcode(sample_binary("short", *PRUSA_DEFAULT))
    text = doc.text_form()
    assert text.startswith(doc.gcode)
    tail = text[len(doc.gcode):]
    assert tail.startswith(b"; generated by PrusaSlicer 2.7.4")
    assert b"\n; nozzle_diameter = 0.4\n" in tail
    assert b"\n; estimated printing time (normal mode) = 31m 3s\n" in tail
    assert b"\n; prusaslicer_config = begin\n" in tail
    assert tail.endswith(b"; prusaslicer_config = end\n")
    assert b"; gcode_flavor = marlin2\n" in tail


def test_metadata_updates_keep_the_block_form(sample_binary):
    """A metadata block given new values is re-encoded with its compression (the settings
    block is deflated), other keys and order kept; the library reads it."""
    data = sample_binary("short", *PRUSA_DEFAULT)
    doc = decode_bgcode(data)
    new = encode_bgcode(doc, doc.gcode, metadata={
        bgcode.PRINT_METADATA: {"filament used [mm]": "12.34", "extra key": "x=y"},
        bgcode.SLICER_METADATA: {"layer_height": "0.25"}})
    assert library_valid(new)
    doc2 = decode_bgcode(new)
    before, after = dict(doc.metadata_of(bgcode.PRINT_METADATA)), \
        dict(doc2.metadata_of(bgcode.PRINT_METADATA))
    assert after == {**before, "filament used [mm]": "12.34", "extra key": "x=y"}
    assert [k for k, _ in doc2.metadata_of(bgcode.PRINT_METADATA)][:len(before)] == list(before)
    assert doc2.value("layer_height", bgcode.SLICER_METADATA) == "0.25"
    slicer = next(b for b in doc2.blocks if b.type == bgcode.SLICER_METADATA)
    assert slicer.compression == 1
    unchanged = encode_bgcode(doc, doc.gcode, metadata={
        bgcode.PRINT_METADATA: dict(doc.metadata_of(bgcode.PRINT_METADATA))})
    assert unchanged == data


def test_rescaled_metadata_writes_as_prusaslicer_does():
    pairs = [("filament used [mm]", "1706.22, 0.00"), ("filament used [cm3]", "4.10"),
             ("filament cost", "0.11"), ("total filament used for wipe tower [g]", "0.00"),
             ("estimated printing time (normal mode)", "31m 3s"),
             ("estimated printing time (silent mode)", "1d 23h 59m 50s"),
             ("estimated first layer printing time (normal mode)", "1m 48s"),
             ("printer_model", "MK4")]
    new = rescaled_metadata(pairs, time_factor=2.0, filament_factor=1.1)
    assert new == {"filament used [mm]": "1876.84, 0.00", "filament used [cm3]": "4.51",
                   "filament cost": "0.12",
                   "estimated printing time (normal mode)": "1h 2m 6s",
                   "estimated printing time (silent mode)": "3d 23h 59m 40s"}
    assert rescaled_metadata(pairs, time_factor=1.0, filament_factor=1.0) == {}
    assert rescaled_metadata([("estimated printing time (normal mode)", "12s")],
                             time_factor=0.5) == {"estimated printing time (normal mode)": "6s"}


def test_no_checksum_files_are_read_and_written_without_one():
    from bg_helpers import binarize

    data = binarize(b"; generated by PrusaSlicer 2.7.4\nG1 X1 Y1\n; printer_model = X\n"
                    b"; filament used [mm] = 1.0\n; prusaslicer_config = begin\n; a = b\n"
                    b"; prusaslicer_config = end\n", 3, 2, checksum=0)
    doc = decode_bgcode(data)
    assert doc.checksum == 0 and doc.gcode == b"G1 X1 Y1\n"
    new = encode_bgcode(doc, b"G1 X1 Y1\nG1 X2 Y2\n")
    assert library_valid(new) and decode_bgcode(new).gcode == b"G1 X1 Y1\nG1 X2 Y2\n"
    assert all(b.end - b.data == b.compressed_size for b in decode_bgcode(new).blocks)  # no CRC


# ----------------------------------------------------------------- damaged files


def _blocks(data: bytes):
    return decode_bgcode(data).blocks


def _recrc(data: bytearray, block) -> None:
    """Make ``block``'s CRC32 right again after an edit (to reach the later checks)."""
    struct.pack_into("<I", data, block.end - 4, zlib.crc32(bytes(data[block.start:block.end - 4])))


@pytest.mark.parametrize("kind", sorted(bgcode.BLOCK_NAMES))
def test_a_block_failing_its_crc_is_named(sample_binary, kind):
    data = sample_binary("short", *PRUSA_DEFAULT)
    block = next(b for b in _blocks(data) if b.type == kind)
    bad = bytearray(data)
    bad[(block.data + block.end) // 2] ^= 0x20
    with pytest.raises(FileFormatError) as exc:
        decode_bgcode(bytes(bad), path="part.bgcode")
    msg = str(exc.value)
    assert msg.startswith("part.bgcode: damaged binary G-code (.bgcode):")
    assert f"{bgcode.BLOCK_NAMES[kind]} block {block.index + 1} (byte {block.start})" in msg
    assert "CRC32" in msg and "\n" not in msg


@pytest.mark.parametrize("cut", [3, 10, 14, 0.3, 0.7, -1])
def test_a_truncated_file_is_refused(sample_binary, cut):
    data = sample_binary("short", *PRUSA_DEFAULT)
    n = cut if isinstance(cut, int) and cut > 0 else \
        len(data) - 1 if cut == -1 else int(len(data) * cut)
    with pytest.raises(FileFormatError, match=r"x\.bgcode: damaged binary G-code.*(cut off|no "
                                              r"G-code block)"):
        decode_bgcode(data[:n], path="x.bgcode")


def test_unknown_compression_type_encoding_and_version_are_named(sample_binary):
    data = sample_binary("short", *PRUSA_DEFAULT)
    blocks = _blocks(data)
    g = blocks[-1]
    bad = bytearray(data)
    struct.pack_into("<H", bad, g.start + 2, 7)  # compression 7
    _recrc(bad, g)
    with pytest.raises(FileFormatError, match=rf"G-code block {g.index + 1} \(byte {g.start}\) "
                                              "has unknown compression 7"):
        decode_bgcode(bytes(bad))
    bad = bytearray(data)
    struct.pack_into("<H", bad, g.data - 2, 5)  # encoding 5
    _recrc(bad, g)
    with pytest.raises(FileFormatError, match="unknown G-code encoding 5"):
        decode_bgcode(bytes(bad))
    bad = bytearray(data)
    struct.pack_into("<H", bad, blocks[1].start, 9)
    with pytest.raises(FileFormatError, match=r"block 2 .*unknown block type 9"):
        decode_bgcode(bytes(bad))
    bad = bytearray(data)
    struct.pack_into("<I", bad, 4, 2)
    with pytest.raises(FileFormatError, match="version 2; only version 1"):
        decode_bgcode(bytes(bad))
    bad = bytearray(data)
    struct.pack_into("<H", bad, 8, 4)
    with pytest.raises(FileFormatError, match="unknown checksum type 4"):
        decode_bgcode(bytes(bad))


def test_a_block_that_does_not_decompress_is_named(sample_binary):
    """Deflate data that is not Deflate (CRC made right): the library's error, the block
    named."""
    data = sample_binary("short", 1, 0)
    g = next(b for b in _blocks(data) if b.type == bgcode.GCODE)
    bad = bytearray(data)
    bad[g.data:g.data + 8] = b"\x00" * 8
    _recrc(bad, g)
    with pytest.raises(FileFormatError, match=rf"G-code block {g.index + 1} .*cannot be read"):
        decode_bgcode(bytes(bad))


def test_blocks_out_of_order_are_refused(sample_binary):
    data = sample_binary("short", *PRUSA_DEFAULT)
    blocks = _blocks(data)
    thumb = next(b for b in blocks if b.type == bgcode.THUMBNAIL)
    moved = data[:thumb.start] + data[thumb.end:] + data[thumb.start:thumb.end]
    with pytest.raises(FileFormatError, match="comes after the G-code blocks"):
        decode_bgcode(moved)


def _text_thumbnails(text: bytes) -> list[bytes]:
    """The images of a text G-code's ``; thumbnail begin`` ... ``; thumbnail end`` comments."""
    import base64
    import re

    return [base64.b64decode(b"".join(line[2:] for line in body.split(b"\n") if line))
            for body in re.findall(rb"; thumbnail begin [^\n]*\n(.*?); thumbnail end", text,
                                   re.DOTALL)]


@pytest.mark.parametrize("name", ["short", "cura_5.9.1_marlin.gcode"])
def test_the_thumbnails_are_kept_as_made(sample_text, sample_binary, name):
    """The images of the text (the slicer's, or two PNGs added where it had none) are the
    thumbnail blocks' data, byte for byte, before and after an encode."""
    from bg_helpers import with_thumbnails

    data = sample_binary(name, 0, 0)
    doc = decode_bgcode(data)
    new = encode_bgcode(doc, doc.gcode + b"G1 X1 Y1\n")
    expect = _text_thumbnails(with_thumbnails(sample_text(name)))
    assert len(expect) >= 2
    if name != "short":
        assert expect == [png(16, 16, 1), png(48, 32, 2)]
    for content in (data, new):
        thumbs = [b for b in _blocks(content) if b.type == bgcode.THUMBNAIL]
        assert [content[b.data:b.data + b.uncompressed_size] for b in thumbs] == expect

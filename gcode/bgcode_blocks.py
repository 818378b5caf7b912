"""Binary G-code (``.bgcode``) framing: the file header, the blocks and their CRC32.

The layout is prusa3d/libbgcode's (``doc/specifications.md``): a 10-byte header (``GCDE``,
version 1, checksum type), then blocks, each with a header (type, compression, sizes),
parameters (an encoding, or a thumbnail's format and size), its data and a CRC32 (zlib's, the
same polynomial). :mod:`gcode.bgcode` decodes and encodes whole files with it.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

from printability.base.errors import FileFormatError

__all__ = [
    "BGCODE_MAGIC", "BLOCK", "BLOCK_NAMES", "CHECKSUM_SIZE", "COMPRESSIONS", "FILE_METADATA",
    "GCODE", "GCODE_ENCODINGS", "HEADER", "MAX_BLOCK_TEXT", "PRINTER_METADATA",
    "PRINT_METADATA", "SLICER_METADATA", "THUMBNAIL", "U16", "U32", "VERSION", "Block",
    "damaged", "read_blocks", "retyped_block",
]

BGCODE_MAGIC = b"GCDE"
"""The first four bytes of a binary G-code file."""

FILE_METADATA, GCODE, SLICER_METADATA, PRINTER_METADATA, PRINT_METADATA, THUMBNAIL = range(6)

BLOCK_NAMES = {FILE_METADATA: "file metadata", GCODE: "G-code", SLICER_METADATA: "slicer metadata",
               PRINTER_METADATA: "printer metadata", PRINT_METADATA: "print metadata",
               THUMBNAIL: "thumbnail"}
"""Block type → name, as the specification numbers them."""

COMPRESSIONS = {0: "none", 1: "deflate", 2: "heatshrink 11/4", 3: "heatshrink 12/4"}
"""Compression code → name."""

GCODE_ENCODINGS = {0: "none", 1: "MeatPack", 2: "MeatPack with comments"}
"""G-code block encoding code → name."""

_METADATA_ENCODINGS = {0: "INI", 1: "JSON"}  # JSON: libbgcode's newer slicer metadata block
VERSION = 1  # the format version this module reads and writes
CHECKSUM_SIZE = {0: 0, 1: 4}
HEADER = struct.Struct("<4sIH")
BLOCK = struct.Struct("<HHI")
U16 = struct.Struct("<H")
U32 = struct.Struct("<I")
MAX_BLOCK_TEXT = 65536  # libbgcode's Binarizer: a block holds at most 64 KiB of text


@dataclass(frozen=True)
class Block:
    """One block of a binary G-code file (offsets into the file's bytes).

    Attributes
    ----------
    index
        0-based position among the file's blocks.
    type
        Block type (:data:`BLOCK_NAMES`).
    compression
        Compression code (:data:`COMPRESSIONS`).
    uncompressed_size, compressed_size
        Sizes of the data, bytes (equal when not compressed).
    start, data, end
        Offsets of the block header, of the data (past the parameters) and past the block.
    encoding
        First parameter: the encoding of a G-code or metadata block, a thumbnail's format.
    """

    index: int
    type: int
    compression: int
    uncompressed_size: int
    compressed_size: int
    start: int
    data: int
    end: int
    encoding: int

    @property
    def name(self) -> str:
        """``"G-code block 7 (byte 10941)"``: how messages name it (1-based)."""
        return f"{BLOCK_NAMES[self.type]} block {self.index + 1} (byte {self.start})"


def damaged(path: str, what: str) -> FileFormatError:
    """The error of a damaged file: ``what`` is wrong, and what to do."""
    return FileFormatError(path, f"damaged binary G-code (.bgcode): {what}; the file is left "
                                 "as it is. Export it again from the slicer")


def read_blocks(data: bytes, path: str) -> tuple[int, list[Block]]:
    """The header's checksum type and every block, framing and CRC32 checked."""
    if len(data) < HEADER.size:
        raise damaged(path, f"the file header is cut off after {len(data)} of "
                             f"{HEADER.size} bytes")
    magic, version, checksum = HEADER.unpack_from(data)
    if magic != BGCODE_MAGIC:
        raise FileFormatError(path, "not a binary G-code (.bgcode) file: it does not start "
                                    "with GCDE")
    if version != VERSION:
        raise FileFormatError(path, f"binary G-code (.bgcode) version {version}; only version "
                                    f"{VERSION} is known (a newer slicer? export plain-text "
                                    "G-code instead)")
    if checksum not in CHECKSUM_SIZE:
        raise damaged(path, f"unknown checksum type {checksum} in the file header (0 none, "
                             "1 CRC32)")
    cs = CHECKSUM_SIZE[checksum]
    blocks: list[Block] = []
    pos, n = HEADER.size, len(data)
    seen_gcode = False
    while pos < n:
        i = len(blocks)
        where = f"block {i + 1} (byte {pos})"
        if pos + BLOCK.size > n:
            raise damaged(path, f"the file is cut off in the header of {where}")
        typ, comp, usize = BLOCK.unpack_from(data, pos)
        if typ not in BLOCK_NAMES:
            raise damaged(path, f"{where} has unknown block type {typ} (0-5 are defined)")
        where = f"{BLOCK_NAMES[typ]} block {i + 1} (byte {pos})"
        if comp not in COMPRESSIONS:
            raise damaged(path, f"{where} has unknown compression {comp} (0 none, 1 deflate, "
                                 "2 heatshrink 11/4, 3 heatshrink 12/4)")
        head = BLOCK.size
        csize = usize
        if comp:
            if pos + head + 4 > n:
                raise damaged(path, f"the file is cut off in the header of {where}")
            csize = U32.unpack_from(data, pos + head)[0]
            head += 4
        params = 6 if typ == THUMBNAIL else 2
        start_data = pos + head + params
        end = start_data + csize + cs
        if end > n:
            raise damaged(path, f"the file is cut off in {where}: it needs {end - pos} bytes, "
                                 f"{n - pos} are left (truncated?)")
        encoding = U16.unpack_from(data, pos + head)[0]
        if cs:
            stored = U32.unpack_from(data, end - 4)[0]
            computed = zlib.crc32(memoryview(data)[pos:end - 4])
            if stored != computed:
                raise damaged(path, f"{where} fails its CRC32 check (stored 0x{stored:08x}, "
                                     f"computed 0x{computed:08x}): it was changed or cut after "
                                     "it was written")
        if typ == GCODE:
            if encoding not in GCODE_ENCODINGS:
                raise damaged(path, f"{where} has unknown G-code encoding {encoding} (0 none, "
                                     "1 MeatPack, 2 MeatPack with comments)")
            seen_gcode = True
        elif seen_gcode:
            raise damaged(path, f"{where} comes after the G-code blocks; the specification "
                                 "puts every metadata and thumbnail block before them")
        blocks.append(Block(i, typ, comp, usize, csize, pos, start_data, end, encoding))
        pos = end
    if not seen_gcode:
        raise damaged(path, "the file has no G-code block (cut off after its metadata?)")
    return checksum, blocks


def retyped_block(block: bytes, block_type: int, checksum: int) -> bytes:
    """A block written as a G-code block, retyped (and its CRC32 made again)."""
    body = U16.pack(block_type) + block[2:len(block) - CHECKSUM_SIZE[checksum]]
    return body + (U32.pack(zlib.crc32(body)) if checksum else b"")

"""Binary G-code (``.bgcode``, PrusaSlicer ≥ 2.7): decode it to text, encode text back.

DESIGN (issue #28). The format is prusa3d/libbgcode's (``doc/specifications.md``): a 10-byte
header (``GCDE``, version 1, checksum type), then blocks: file metadata (optional), printer
metadata, thumbnails, print metadata, slicer metadata and G-code blocks, each with a header
(type, compression, sizes), parameters (an encoding, or a thumbnail's format and size), its
data and a CRC32. G-code blocks are compressed with Deflate or Heatshrink (11/4 or 12/4) and
may be MeatPack-encoded; metadata are ``key=value`` lines.

The codecs are libbgcode's own, through its Python binding as published on PyPI by
``pybgcode-jneilliii`` (prusa3d builds the binding but publishes no wheel; that fork
publishes libbgcode's binding unchanged but for fixes, with wheels for CPython 3.10-3.13 on
Linux x86-64/aarch64, Windows and macOS): Heatshrink and MeatPack in Python would cost
seconds per file, and a codec of our own could drift from what the printers' firmware
decodes, while a wheel needs no compiler at install. The binding's writer
(``Binarizer``) cannot be handed metadata from Python and its reader and writer work on
``FILE*``, so the library is used block by block: a G-code block is decoded by
``GCodeBlock.read_data`` and encoded by ``GCodeBlock.write``, the very calls its Binarizer
makes, on a scratch file of blocks laid out here. Everything else is done here on the bytes:
the framing, the CRC32 (zlib's, the same polynomial), the order of the blocks and the
``key=value`` metadata; metadata blocks go through the same codec calls (their data is laid
out as a G-code block's with encoding 0, then the block type is set back), so that the
library's metadata parser, which never returns on a line without ``=``, is not used.

Decoded text: the G-code blocks' text, joined. Blocks whose text post-processing left as it
was are written back byte for byte; the rest is re-encoded with the compression and encoding
of the blocks it replaces, in blocks of at most 64 KiB of text cut at line ends (libbgcode's
rule). MeatPack is lossy by design (it drops the comments after a command and the blanks in
``G`` lines, which its decoder puts back before the parameter letters, and MeatPack without
comments drops every comment): re-encoding is exact up to that, and unchanged blocks stay
exact because they are not re-encoded. Every other block is kept byte for byte, except the
print and printer metadata a caller updates (:func:`rescaled_metadata`).
"""

from __future__ import annotations

import os
import re
import struct
import tempfile
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from printability.base.errors import FileFormatError

__all__ = [
    "BGCODE_MAGIC",
    "BLOCK_NAMES",
    "COMPRESSIONS",
    "GCODE_ENCODINGS",
    "BinaryGCode",
    "Block",
    "decode_bgcode",
    "encode_bgcode",
    "encode_gcode_blocks",
    "is_bgcode",
    "rescaled_metadata",
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
_VERSION = 1
_CHECKSUM_SIZE = {0: 0, 1: 4}
_HEADER = struct.Struct("<4sIH")
_BLOCK = struct.Struct("<HHI")
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_MAX_BLOCK_TEXT = 65536  # libbgcode's Binarizer: a block holds at most 64 KiB of text
# MeatPack's "disable packing" signal: the library's decoder then copies the bytes that
# follow, which is how text reaches GCodeBlock.write (see the module docstring)
_MEATPACK_PLAIN = b"\xff\xff\xfa"
_MISSING_LIBRARY = ("reading and writing binary G-code needs libbgcode's Python binding, the "
                    "package pybgcode-jneilliii (pip install pybgcode-jneilliii); it is not "
                    "installed")


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


@dataclass(frozen=True, eq=False)
class BinaryGCode:
    """A decoded binary G-code file (build it with :func:`decode_bgcode`).

    Attributes
    ----------
    path
        Name used in messages.
    data
        The file's bytes.
    checksum
        Checksum type of the file (0 none, 1 CRC32).
    blocks
        Every block, in file order.
    gcode_texts
        Decoded text of each G-code block, in order (UTF-8 bytes).
    metadata
        Block index → the ``(key, value)`` pairs of each INI metadata block.
    """

    path: str
    data: bytes
    checksum: int
    blocks: tuple[Block, ...]
    gcode_texts: tuple[bytes, ...]
    metadata: Mapping[int, tuple[tuple[str, str], ...]] = field(default_factory=dict)

    @property
    def gcode(self) -> bytes:
        """The G-code: every G-code block's text, joined."""
        return b"".join(self.gcode_texts)

    @property
    def gcode_blocks(self) -> tuple[Block, ...]:
        """The G-code blocks, in order."""
        return tuple(b for b in self.blocks if b.type == GCODE)

    def metadata_of(self, block_type: int) -> tuple[tuple[str, str], ...]:
        """The ``(key, value)`` pairs of the first INI metadata block of ``block_type``."""
        for b in self.blocks:
            if b.type == block_type and b.index in self.metadata:
                return self.metadata[b.index]
        return ()

    def value(self, key: str, block_type: int = PRINT_METADATA) -> str | None:
        """A metadata value (the first block of ``block_type`` holding ``key``), or None."""
        for b in self.blocks:
            if b.type == block_type:
                for k, v in self.metadata.get(b.index, ()):
                    if k == key:
                        return v
        return None

    @property
    def compression(self) -> int:
        """Compression code of the (first) G-code block."""
        return self.gcode_blocks[0].compression

    @property
    def encoding(self) -> int:
        """Encoding code of the (first) G-code block."""
        return self.gcode_blocks[0].encoding

    def describe(self) -> str:
        """``"binary G-code, heatshrink 12/4, MeatPack with comments"``."""
        return (f"binary G-code, {COMPRESSIONS[self.compression]}, "
                f"{GCODE_ENCODINGS[self.encoding]} encoding")

    def trailer(self) -> bytes:
        """The metadata as the comments PrusaSlicer's text G-code ends with.

        ``; generated by <Producer>``, then the printer and print metadata as
        ``; key = value`` and the slicer's settings between ``; prusaslicer_config = begin``
        and ``= end``: what a G-code reader looks for at the end of a text file (the
        slicer, its flavor, its nozzle). Preceded by a line end when the G-code has none.
        """
        out = [b"\n"] if self.gcode_texts and not self.gcode_texts[-1].endswith(b"\n") else []
        producer = self.value("Producer", FILE_METADATA)
        if producer:
            on = self.value("Produced on", FILE_METADATA)
            out.append(f"; generated by {producer}{' on ' + on if on else ''}\n".encode())
        for kind in (PRINTER_METADATA, PRINT_METADATA):
            out.extend(f"; {k} = {v}\n".encode() for k, v in self.metadata_of(kind))
        config = self.metadata_of(SLICER_METADATA)
        if config:
            out.append(b"; prusaslicer_config = begin\n")
            out.extend(f"; {k} = {v}\n".encode() for k, v in config)
            out.append(b"; prusaslicer_config = end\n")
        return b"".join(out)

    def text_form(self) -> bytes:
        """The G-code followed by :meth:`trailer`: the file as text G-code.

        Line ``n`` of it is line ``n`` of the G-code; the metadata come after the last
        G-code line.
        """
        return self.gcode + self.trailer()


def is_bgcode(data: bytes | bytearray | memoryview) -> bool:
    """True when ``data`` starts like a binary G-code file (its magic ``GCDE``), whatever
    the file's name."""
    return bytes(data[:4]) == BGCODE_MAGIC


# ----------------------------------------------------------------- framing


def _damaged(path: str, what: str) -> FileFormatError:
    return FileFormatError(path, f"damaged binary G-code (.bgcode): {what}; the file is left "
                                 "as it is. Export it again from the slicer")


def _blocks(data: bytes, path: str) -> tuple[int, list[Block]]:
    """The header's checksum type and every block, framing and CRC32 checked."""
    if len(data) < _HEADER.size:
        raise _damaged(path, f"the file header is cut off after {len(data)} of "
                             f"{_HEADER.size} bytes")
    magic, version, checksum = _HEADER.unpack_from(data)
    if magic != BGCODE_MAGIC:
        raise FileFormatError(path, "not a binary G-code (.bgcode) file: it does not start "
                                    "with GCDE")
    if version != _VERSION:
        raise FileFormatError(path, f"binary G-code (.bgcode) version {version}; only version "
                                    f"{_VERSION} is known (a newer slicer? export plain-text "
                                    "G-code instead)")
    if checksum not in _CHECKSUM_SIZE:
        raise _damaged(path, f"unknown checksum type {checksum} in the file header (0 none, "
                             "1 CRC32)")
    cs = _CHECKSUM_SIZE[checksum]
    blocks: list[Block] = []
    pos, n = _HEADER.size, len(data)
    seen_gcode = False
    while pos < n:
        i = len(blocks)
        where = f"block {i + 1} (byte {pos})"
        if pos + _BLOCK.size > n:
            raise _damaged(path, f"the file is cut off in the header of {where}")
        typ, comp, usize = _BLOCK.unpack_from(data, pos)
        if typ not in BLOCK_NAMES:
            raise _damaged(path, f"{where} has unknown block type {typ} (0-5 are defined)")
        where = f"{BLOCK_NAMES[typ]} block {i + 1} (byte {pos})"
        if comp not in COMPRESSIONS:
            raise _damaged(path, f"{where} has unknown compression {comp} (0 none, 1 deflate, "
                                 "2 heatshrink 11/4, 3 heatshrink 12/4)")
        head = _BLOCK.size
        csize = usize
        if comp:
            if pos + head + 4 > n:
                raise _damaged(path, f"the file is cut off in the header of {where}")
            csize = _U32.unpack_from(data, pos + head)[0]
            head += 4
        params = 6 if typ == THUMBNAIL else 2
        start_data = pos + head + params
        end = start_data + csize + cs
        if end > n:
            raise _damaged(path, f"the file is cut off in {where}: it needs {end - pos} bytes, "
                                 f"{n - pos} are left (truncated?)")
        encoding = _U16.unpack_from(data, pos + head)[0]
        if cs:
            stored = _U32.unpack_from(data, end - 4)[0]
            computed = zlib.crc32(memoryview(data)[pos:end - 4])
            if stored != computed:
                raise _damaged(path, f"{where} fails its CRC32 check (stored 0x{stored:08x}, "
                                     f"computed 0x{computed:08x}): it was changed or cut after "
                                     "it was written")
        if typ == GCODE:
            if encoding not in GCODE_ENCODINGS:
                raise _damaged(path, f"{where} has unknown G-code encoding {encoding} (0 none, "
                                     "1 MeatPack, 2 MeatPack with comments)")
            seen_gcode = True
        elif seen_gcode:
            raise _damaged(path, f"{where} comes after the G-code blocks; the specification "
                                 "puts every metadata and thumbnail block before them")
        blocks.append(Block(i, typ, comp, usize, csize, pos, start_data, end, encoding))
        pos = end
    if not seen_gcode:
        raise _damaged(path, "the file has no G-code block (cut off after its metadata?)")
    return checksum, blocks


# ----------------------------------------------------------------- the library


def _library() -> Any:
    try:
        from pybgcode import _bgcode
    except ImportError:  # pragma: no cover - a declared dependency
        raise FileFormatError("binary G-code", _MISSING_LIBRARY) from None
    return _bgcode


class _ScratchFile:
    """A ``FILE*`` of the binding on ``data`` (in memory where the binding can) or on a
    scratch file of ``folder``; closed by ``close``."""

    def __init__(self, lib: Any, data: bytes, folder: str) -> None:
        self._data = data  # memopen reads this buffer: it must live as long as the FILE
        if hasattr(lib, "memopen"):
            self.handle = lib.memopen(data)
        else:  # Windows: no fmemopen
            name = os.path.join(folder, "in.bgcode")
            with open(name, "wb") as fh:
                fh.write(data)
            self.handle = lib.open(name, "rb")
        self._lib = lib

    def close(self) -> None:
        self._lib.close(self.handle)


def _scratch_header() -> bytes:
    return _HEADER.pack(BGCODE_MAGIC, _VERSION, 0)


def _scratch_block(compression: int, usize: int, csize: int, encoding: int,
                   payload: bytes | memoryview) -> bytes:
    head = _BLOCK.pack(GCODE, compression, usize)
    if compression:
        head += _U32.pack(csize)
    return head + _U16.pack(encoding) + bytes(payload)


def _decode_payloads(items: Sequence[tuple[int, int, int, int, memoryview]],
                     fail: Callable[[int, str], Exception]) -> list[str]:
    """Decompress and decode each ``(compression, uncompressed size, compressed size,
    encoding, data)`` with the library; ``fail(i, reason)`` makes the error of item ``i``."""
    lib = _library()
    scratch = b"".join([_scratch_header(),
                        *(_scratch_block(c, u, s, e, d) for c, u, s, e, d in items)])
    ok = lib.EResult.Success
    out: list[str] = []
    with tempfile.TemporaryDirectory(prefix="printability-bgcode-") as folder:
        f = _ScratchFile(lib, scratch, folder)
        try:
            header = lib.FileHeader()
            if lib.read_header(f.handle, header) != ok:  # pragma: no cover - laid out above
                raise fail(0, "the library cannot read it")
            bh = lib.BlockHeader()
            for i in range(len(items)):
                res = lib.read_next_block_header(f.handle, header, bh)
                if res == ok:
                    block = lib.GCodeBlock()
                    res = block.read_data(f.handle, header, bh)
                if res != ok:
                    raise fail(i, f"the library cannot decode it ({lib.translate_result(res)})")
                try:
                    out.append(block.raw_data)
                except UnicodeDecodeError as exc:
                    raise fail(i, f"it decodes to text that is not UTF-8 (byte "
                                  f"0x{exc.object[exc.start]:02x})") from None
        finally:
            f.close()
    return out


def _encode_payloads(items: Sequence[tuple[int, int, bytes]], checksum: int,
                     path: str = "<bytes>") -> list[bytes]:
    """Each ``(compression, encoding, text)`` as a whole G-code block written by the library
    (header, encoding, data and, with ``checksum`` 1, CRC32)."""
    if not items:
        return []
    lib = _library()
    parts = [_scratch_header()]
    for _, enc, text in items:
        payload = _MEATPACK_PLAIN + text if enc else text
        parts.append(_scratch_block(0, len(payload), len(payload), enc, payload))
    ok = lib.EResult.Success
    with tempfile.TemporaryDirectory(prefix="printability-bgcode-") as folder:
        f = _ScratchFile(lib, b"".join(parts), folder)
        out_name = os.path.join(folder, "out.bgcode")
        out = lib.open(out_name, "wb")
        try:
            header = lib.FileHeader()
            res = lib.read_header(f.handle, header)
            bh = lib.BlockHeader()
            for comp, _, _ in items:
                if res == ok:
                    res = lib.read_next_block_header(f.handle, header, bh)
                if res == ok:
                    block = lib.GCodeBlock()
                    res = block.read_data(f.handle, header, bh)
                if res == ok:
                    res = block.write(out, lib.CompressionType(comp),
                                      lib.ChecksumType(checksum))
                if res != ok:
                    raise FileFormatError(path, "libbgcode cannot encode the G-code as "
                                                "binary G-code "
                                                f"({lib.translate_result(res)})")
        finally:
            lib.close(out)
            f.close()
        with open(out_name, "rb") as fh:
            written = fh.read()
    blocks, pos, cs = [], 0, _CHECKSUM_SIZE[checksum]
    for comp, _, _ in items:
        usize = _U32.unpack_from(written, pos + 4)[0]
        head = _BLOCK.size + (4 if comp else 0)
        size = _U32.unpack_from(written, pos + _BLOCK.size)[0] if comp else usize
        end = pos + head + 2 + size + cs
        blocks.append(written[pos:end])
        pos = end
    return blocks


def encode_gcode_blocks(texts: Sequence[bytes], *, compression: int, encoding: int,
                        checksum: int = 1) -> list[bytes]:
    """G-code blocks of ``texts``, one each, written by libbgcode.

    Parameters
    ----------
    texts
        The text of each block (libbgcode's writer puts at most 64 KiB in one).
    compression, encoding
        Codes of :data:`COMPRESSIONS` and :data:`GCODE_ENCODINGS`.
    checksum
        0: no checksum, 1: CRC32.

    Returns
    -------
    list of bytes
        Whole blocks: header, parameters, data, checksum.
    """
    if compression not in COMPRESSIONS or encoding not in GCODE_ENCODINGS or \
            checksum not in _CHECKSUM_SIZE:
        raise ValueError(f"unknown compression {compression}, encoding {encoding} or "
                         f"checksum {checksum}")
    return _encode_payloads([(compression, encoding, bytes(t)) for t in texts], checksum)


def _with_type(block: bytes, block_type: int, checksum: int) -> bytes:
    """A block written as a G-code block, retyped (and its CRC32 made again)."""
    body = _U16.pack(block_type) + block[2:len(block) - _CHECKSUM_SIZE[checksum]]
    return body + (_U32.pack(zlib.crc32(body)) if checksum else b"")


# ----------------------------------------------------------------- decode


def _parse_ini(text: str) -> tuple[tuple[str, str], ...]:
    """``key=value`` lines (the first ``=`` splits; other lines are skipped)."""
    pairs = []
    for line in text.split("\n"):
        k, eq, v = line.partition("=")
        if eq:
            pairs.append((k, v))
    return tuple(pairs)


def decode_bgcode(data: bytes, *, path: str = "<bytes>") -> BinaryGCode:
    """Check and decode a binary G-code file.

    Every block's framing and CRC32 are checked; the G-code blocks and the INI metadata
    blocks are decoded by libbgcode (thumbnails and other blocks are only kept).

    Parameters
    ----------
    data
        The file's bytes (starting with ``GCDE``).
    path
        Name used in messages.

    Returns
    -------
    BinaryGCode

    Raises
    ------
    FileFormatError
        Not binary G-code, an unknown version, a block cut off, failing its CRC32, of an
        unknown type, compression or encoding, out of order, or that does not decode. The
        message names the file and the block.
    """
    data = bytes(data)
    checksum, blocks = _blocks(data, path)
    view = memoryview(data)
    wanted = [b for b in blocks
              if b.type == GCODE or (b.type != THUMBNAIL and b.encoding == 0)]
    items = [(b.compression, b.uncompressed_size, b.compressed_size,
              b.encoding if b.type == GCODE else 0, view[b.data:b.data + b.compressed_size])
             for b in wanted]

    def fail(i: int, reason: str) -> FileFormatError:
        return _damaged(path, f"{wanted[i].name} cannot be read: {reason}")

    texts = _decode_payloads(items, fail)
    gcode: list[bytes] = []
    metadata: dict[int, tuple[tuple[str, str], ...]] = {}
    for b, text in zip(wanted, texts, strict=True):
        if "\0" in text:
            raise _damaged(path, f"{b.name} decodes to data holding NUL bytes, not text")
        if b.type == GCODE:
            gcode.append(text.encode("utf-8"))
        else:
            metadata[b.index] = _parse_ini(text)
    return BinaryGCode(path=path, data=data, checksum=checksum, blocks=tuple(blocks),
                       gcode_texts=tuple(gcode), metadata=metadata)


# ----------------------------------------------------------------- encode


def _split_text(text: bytes, limit: int = _MAX_BLOCK_TEXT) -> list[bytes]:
    """``text`` in pieces of at most ``limit`` bytes cut after a line end (libbgcode's
    Binarizer packs whole lines while they fit); a longer line is a piece of its own."""
    out: list[bytes] = []
    start, n = 0, len(text)
    while n - start > limit:
        cut = text.rfind(b"\n", start, start + limit) + 1
        if cut <= start:
            nl = text.find(b"\n", start + limit)
            cut = n if nl < 0 else nl + 1
        out.append(text[start:cut])
        start = cut
    if start < n:
        out.append(text[start:])
    return out


def _kept_blocks(texts: Sequence[bytes], gcode: bytes) -> tuple[int, int]:
    """How many G-code blocks at the start and at the end ``gcode`` holds unchanged, each
    starting and ending at a line end of ``gcode`` (a block never holds part of a line:
    MeatPack would end it)."""
    m, n = len(texts), len(gcode)
    head = pos = 0
    while head < m and gcode.startswith(texts[head], pos) and \
            (texts[head].endswith(b"\n") or pos + len(texts[head]) == n):
        pos += len(texts[head])
        head += 1
    tail, end = 0, n
    while tail < m - head:
        t = texts[m - 1 - tail]
        start = end - len(t)
        if start < pos or not gcode.endswith(t, pos, end) or \
                not (start == 0 or gcode[start - 1] == 10) or \
                not (t.endswith(b"\n") or end == n):
            break
        end = start
        tail += 1
    return head, tail


def _updated_ini(pairs: Sequence[tuple[str, str]], updates: Mapping[str, str]) -> bytes:
    """The INI text of ``pairs`` with the values of ``updates`` (new keys appended)."""
    seen = set()
    lines = []
    for k, v in pairs:
        if k in updates:
            v = updates[k]
            seen.add(k)
        lines.append(f"{k}={v}\n")
    lines.extend(f"{k}={v}\n" for k, v in updates.items() if k not in seen)
    return "".join(lines).encode("utf-8")


def encode_bgcode(doc: BinaryGCode, gcode: bytes, *,
                  metadata: Mapping[int, Mapping[str, str]] | None = None) -> bytes:
    """``doc`` with ``gcode`` as its G-code and ``metadata`` updated.

    The G-code blocks at the start and at the end whose text ``gcode`` still holds are kept
    byte for byte; the text between them is encoded anew with the compression and encoding
    of the first block it replaces, in blocks of at most 64 KiB of text cut at line ends.
    Every other block is kept byte for byte, but for the metadata blocks given new values.
    ``encode_bgcode(doc, doc.gcode)`` is ``doc.data``.

    Parameters
    ----------
    doc
        The decoded file (:func:`decode_bgcode`).
    gcode
        The new G-code text.
    metadata
        Block type (``PRINT_METADATA``...) → ``{key: new value}`` for the first INI block of
        that type (keys not there are appended). A block whose values do not change is kept.

    Returns
    -------
    bytes
        The new file.
    """
    metadata = metadata or {}
    texts = doc.gcode_texts
    gblocks = doc.gcode_blocks
    head, tail = _kept_blocks(texts, gcode)
    start = sum(len(t) for t in texts[:head])
    stop = len(gcode) - sum(len(t) for t in texts[len(texts) - tail:])
    like = gblocks[head] if head < len(gblocks) else gblocks[-1]
    pieces = _split_text(gcode[start:stop])
    new_gcode = _encode_payloads([(like.compression, like.encoding, p) for p in pieces],
                                 doc.checksum, doc.path)

    data = doc.data
    out = [data[:_HEADER.size]]
    meta_items, meta_slots = [], []
    done: set[int] = set()
    for b in doc.blocks:
        if b.type == GCODE:
            continue
        updates = metadata.get(b.type)
        if updates and b.type not in done and b.index in doc.metadata:
            done.add(b.type)
            pairs = doc.metadata[b.index]
            if any(dict(pairs).get(k) != v for k, v in updates.items()):
                meta_slots.append((len(out), b.type))
                meta_items.append((b.compression, 0, _updated_ini(pairs, updates)))
        out.append(data[b.start:b.end])
    for (slot, typ), block in zip(meta_slots,
                                  _encode_payloads(meta_items, doc.checksum, doc.path),
                                  strict=True):
        out[slot] = _with_type(block, typ, doc.checksum)
    out.extend(data[b.start:b.end] for b in gblocks[:head])
    out.extend(new_gcode)
    out.extend(data[b.start:b.end] for b in gblocks[len(gblocks) - tail:])
    return b"".join(out)


# ----------------------------------------------------------------- metadata


_TIME_KEYS = ("estimated printing time (normal mode)", "estimated printing time (silent mode)")
_FILAMENT_KEYS = ("filament used [mm]", "filament used [cm3]", "filament used [g]",
                  "filament cost", "total filament used [g]", "total filament cost")
_DHMS = re.compile(r"^\s*(?:(\d+)d\s*)?(?:(\d+)h\s*)?(?:(\d+)m\s*)?(?:(\d+)s)?\s*$")
_NUMBER = re.compile(r"-?\d+(?:\.(\d+))?")


def _dhms(seconds: float) -> str:
    """PrusaSlicer's way of writing a duration: ``1d 2h 3m 4s``, ``2h 3m 4s``, ``3m 4s``,
    ``4s``."""
    s = max(0, round(seconds))
    d, s = divmod(s, 86400)
    h, s = divmod(s, 3600)
    m, s = divmod(s, 60)
    if d:
        return f"{d}d {h}h {m}m {s}s"
    if h:
        return f"{h}h {m}m {s}s"
    return f"{m}m {s}s" if m else f"{s}s"


def _scaled_time(value: str, factor: float) -> str | None:
    m = _DHMS.match(value)
    if m is None or not any(m.groups()):
        return None
    d, h, mi, s = (int(g or 0) for g in m.groups())
    return _dhms((((d * 24 + h) * 60 + mi) * 60 + s) * factor)


def _scaled_numbers(value: str, factor: float) -> str:
    """Every number of ``value`` (a per-extruder list ``1.50, 0.00``) times ``factor``,
    written with as many decimals as it had."""
    def one(m: re.Match) -> str:
        decimals = len(m.group(1) or "")
        return f"{float(m.group(0)) * factor:.{decimals}f}"

    return _NUMBER.sub(one, value)


def rescaled_metadata(pairs: Sequence[tuple[str, str]], *, time_factor: float | None = None,
                      filament_factor: float | None = None) -> dict[str, str]:
    """New values of the metadata PrusaSlicer derives from the G-code, scaled.

    ``estimated printing time (normal|silent mode)`` are multiplied by ``time_factor`` (the
    ratio of the print times of the new and the old G-code, on any one model) and written
    as PrusaSlicer writes them; ``filament used [mm|cm3|g]``, ``filament cost`` and ``total
    filament used [g]`` / ``total filament cost`` by ``filament_factor`` (the ratio of the
    filament the extruding moves push), keeping their decimals. The first-layer times and
    the wipe tower's share are left as they are (no per-layer or per-feature estimate).

    Parameters
    ----------
    pairs
        A metadata block's ``(key, value)`` pairs.
    time_factor, filament_factor
        None: leave those keys alone.

    Returns
    -------
    dict
        Only the keys whose value changes.
    """
    out: dict[str, str] = {}
    for k, v in pairs:
        new = None
        if time_factor is not None and k in _TIME_KEYS:
            new = _scaled_time(v, time_factor)
        elif filament_factor is not None and k in _FILAMENT_KEYS:
            new = _scaled_numbers(v, filament_factor)
        if new is not None and new != v:
            out[k] = new
    return out

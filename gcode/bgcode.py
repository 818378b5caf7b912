"""Binary G-code (``.bgcode``, PrusaSlicer ≥ 2.7): decode it to text, encode text back.

DESIGN (issue #28). The format is prusa3d/libbgcode's (``doc/specifications.md``): a 10-byte
header (``GCDE``, version 1, checksum type), then blocks: file metadata (optional), printer
metadata, thumbnails, print metadata, slicer metadata and G-code blocks, each with a header
(type, compression, sizes), parameters (an encoding, or a thumbnail's format and size), its
data and a CRC32. G-code blocks are compressed with Deflate or Heatshrink (11/4 or 12/4) and
may be MeatPack-encoded; metadata are ``key=value`` lines.

The codecs are libbgcode's own, through its Python binding (``pybgcode-jneilliii``), used
block by block on scratch files laid out here (:mod:`gcode.bgcode_codec`); everything else is
done on the bytes: the framing and the CRC32 (:mod:`gcode.bgcode_blocks`), the order of the
blocks and the ``key=value`` metadata (:mod:`gcode.bgcode_metadata`).

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

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from gcode.bgcode_blocks import (
    BGCODE_MAGIC,
    BLOCK_NAMES,
    COMPRESSIONS,
    FILE_METADATA,
    GCODE,
    GCODE_ENCODINGS,
    HEADER,
    MAX_BLOCK_TEXT,
    PRINT_METADATA,
    PRINTER_METADATA,
    SLICER_METADATA,
    THUMBNAIL,
    Block,
    damaged,
    read_blocks,
    retyped_block,
)
from gcode.bgcode_codec import decode_payloads, encode_gcode_blocks, encode_payloads
from gcode.bgcode_metadata import parse_ini, rescaled_metadata, updated_ini
from printability.base.errors import FileFormatError

__all__ = [
    "BGCODE_MAGIC",
    "BLOCK_NAMES",
    "COMPRESSIONS",
    "FILE_METADATA",
    "GCODE",
    "GCODE_ENCODINGS",
    "PRINTER_METADATA",
    "PRINT_METADATA",
    "SLICER_METADATA",
    "THUMBNAIL",
    "BinaryGCode",
    "Block",
    "decode_bgcode",
    "encode_bgcode",
    "encode_gcode_blocks",
    "is_bgcode",
    "rescaled_metadata",
]


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


# ----------------------------------------------------------------- decode


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
    checksum, blocks = read_blocks(data, path)
    view = memoryview(data)
    wanted = [b for b in blocks
              if b.type == GCODE or (b.type != THUMBNAIL and b.encoding == 0)]
    items = [(b.compression, b.uncompressed_size, b.compressed_size,
              b.encoding if b.type == GCODE else 0, view[b.data:b.data + b.compressed_size])
             for b in wanted]

    def fail(i: int, reason: str) -> FileFormatError:
        return damaged(path, f"{wanted[i].name} cannot be read: {reason}")

    texts = decode_payloads(items, fail)
    gcode: list[bytes] = []
    metadata: dict[int, tuple[tuple[str, str], ...]] = {}
    for b, text in zip(wanted, texts, strict=True):
        if "\0" in text:
            raise damaged(path, f"{b.name} decodes to data holding NUL bytes, not text")
        if b.type == GCODE:
            gcode.append(text.encode("utf-8"))
        else:
            metadata[b.index] = parse_ini(text)
    return BinaryGCode(path=path, data=data, checksum=checksum, blocks=tuple(blocks),
                       gcode_texts=tuple(gcode), metadata=metadata)


# ----------------------------------------------------------------- encode


def _split_text(text: bytes, limit: int = MAX_BLOCK_TEXT) -> list[bytes]:
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
    new_gcode = encode_payloads([(like.compression, like.encoding, p) for p in pieces],
                                 doc.checksum, doc.path)

    data = doc.data
    out = [data[:HEADER.size]]
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
                meta_items.append((b.compression, 0, updated_ini(pairs, updates)))
        out.append(data[b.start:b.end])
    for (slot, typ), block in zip(meta_slots,
                                  encode_payloads(meta_items, doc.checksum, doc.path),
                                  strict=True):
        out[slot] = retyped_block(block, typ, doc.checksum)
    out.extend(data[b.start:b.end] for b in gblocks[:head])
    out.extend(new_gcode)
    out.extend(data[b.start:b.end] for b in gblocks[len(gblocks) - tail:])
    return b"".join(out)

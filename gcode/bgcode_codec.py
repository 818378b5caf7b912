"""Binary G-code (``.bgcode``) codecs: Deflate, Heatshrink and MeatPack, by libbgcode.

The codecs are libbgcode's own, through its Python binding as published on PyPI by
``pybgcode-jneilliii`` (prusa3d builds the binding but publishes no wheel; that fork
publishes libbgcode's binding unchanged but for fixes, with wheels for CPython 3.10-3.13 on
Linux x86-64/aarch64, Windows and macOS): Heatshrink and MeatPack in Python would cost
seconds per file, and a codec of our own could drift from what the printers' firmware
decodes, while a wheel needs no compiler at install. The binding's writer
(``Binarizer``) cannot be handed metadata from Python and its reader and writer work on
``FILE*``, so the library is used block by block: a G-code block is decoded by
``GCodeBlock.read_data`` and encoded by ``GCodeBlock.write``, the very calls its Binarizer
makes, on a scratch file of blocks laid out here (:mod:`gcode.bgcode_blocks` frames them).
Metadata blocks go through the same codec calls (their data is laid out as a G-code block's
with encoding 0, then the block type is set back), so that the library's metadata parser,
which never returns on a line without ``=``, is not used.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Sequence
from typing import Any

from gcode.bgcode_blocks import (
    BGCODE_MAGIC,
    BLOCK,
    CHECKSUM_SIZE,
    COMPRESSIONS,
    GCODE,
    GCODE_ENCODINGS,
    HEADER,
    U16,
    U32,
    VERSION,
)
from printability.base.errors import FileFormatError

__all__ = ["decode_payloads", "encode_gcode_blocks", "encode_payloads"]

# MeatPack's "disable packing" signal: the library's decoder then copies the bytes that
# follow, which is how text reaches GCodeBlock.write (see the module docstring)
_MEATPACK_PLAIN = b"\xff\xff\xfa"
_MISSING_LIBRARY = ("reading and writing binary G-code needs libbgcode's Python binding, the "
                    "package pybgcode-jneilliii (pip install pybgcode-jneilliii); it is not "
                    "installed")


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
    return HEADER.pack(BGCODE_MAGIC, VERSION, 0)


def _scratch_block(compression: int, usize: int, csize: int, encoding: int,
                   payload: bytes | memoryview) -> bytes:
    head = BLOCK.pack(GCODE, compression, usize)
    if compression:
        head += U32.pack(csize)
    return head + U16.pack(encoding) + bytes(payload)


def decode_payloads(items: Sequence[tuple[int, int, int, int, memoryview]],
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


def encode_payloads(items: Sequence[tuple[int, int, bytes]], checksum: int,
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
    blocks, pos, cs = [], 0, CHECKSUM_SIZE[checksum]
    for comp, _, _ in items:
        usize = U32.unpack_from(written, pos + 4)[0]
        head = BLOCK.size + (4 if comp else 0)
        size = U32.unpack_from(written, pos + BLOCK.size)[0] if comp else usize
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
            checksum not in CHECKSUM_SIZE:
        raise ValueError(f"unknown compression {compression}, encoding {encoding} or "
                         f"checksum {checksum}")
    return encode_payloads([(compression, encoding, bytes(t)) for t in texts], checksum)

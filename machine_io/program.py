"""A G-code file made ready to stream: the commands to send, where each came from,
the machine state at any line and a motion-time estimate.

Comments and blank lines are not sent; a line already framed by another host
(``N12 G1 X1*34``) loses its old number and checksum (the host numbers lines
itself); ``M110`` (set line number) is not sent either, because the host owns
the numbering. Everything else is sent exactly as written, trimmed.

Binary G-code (``.bgcode``, PrusaSlicer ≥ 2.7; recognised by its first bytes, ``GCDE``,
whatever the file's name) is decoded first (:func:`gcode.bgcode.decode_bgcode`: every
block's CRC checked, the G-code blocks decompressed and MeatPack-decoded) and its G-code
is sent by the same rules: the commands of the same G-code as text, in the same order.
Line numbers (messages, ``--resume-from``) are then those of the decoded G-code, which
has neither the thumbnails nor the metadata of the text file.

The state tracker (:class:`MachineState`, :func:`state_at`) follows the modal
state the firmware would have after a given line — positions including the
rotary axis and E, absolute/relative modes, feed rate, temperatures, fan — so
that a print can be resumed after a lost connection.
"""

from __future__ import annotations

import io
import itertools
import math
import os
import re
import stat
import struct
from array import array
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, BinaryIO, overload

from gcode.bgcode import decode_bgcode, is_bgcode
from machine_io.protocol import EXTRA_AXES, command_code
from machine_io.session import StreamReport
from printability.base.errors import InputError, PrintabilityOSError, ResourceError, excerpt

__all__ = [
    "MachineState",
    "PackedNumbers",
    "PackedTexts",
    "Program",
    "check_gcode_file",
    "check_line_lengths",
    "executed_as_streamed",
    "load_program",
    "parse_program",
    "restore_commands",
    "state_at",
]

_FRAMED = re.compile(r"^[Nn]\d+\s*(.*?)\s*(?:\*\d+)?$")
_WORD = re.compile(r"([A-Za-z])\s*([+-]?(?:\d+\.?\d*|\.\d+))")
_CONTROL = re.compile(r"[\x00-\x08\x0a-\x1f\x7f]")
# Marlin's MAX_CMD_SIZE: longer lines are cut by the firmware.
DEFAULT_MAX_LINE = 96
_HEATING_WAITS = {"M109": "T", "M190": "B", "M191": "C"}
_HEATING_SETS = {"M104": "T", "M140": "B", "M141": "C"}
# A file is read in pieces of this size: the whole file is never in memory at once.
_CHUNK = 1 << 20
# Bytes a program keeps per command besides its text: end offset, file line, seconds.
BYTES_PER_COMMAND = 24
# Skipped lines listed in Program.skipped (a file of nothing but M110 would list millions).
_MAX_SKIPPED = 1000
# Binary G-code: MeatPack puts two characters in a byte and its decoder puts back a blank
# before each parameter letter of a G line, so a MeatPack-encoded G-code block decodes to at
# most 4 bytes of text per byte of its (decompressed) data; PrusaSlicer's files decode to
# 1.7-1.9, "G0 X X X..." to 3.5. Unencoded blocks state their text size exactly.
MEATPACK_EXPANSION = 4
_BG_HEADER = struct.Struct("<4sIH")  # magic, version, checksum type (gcode.bgcode's framing)
_BG_BLOCK = struct.Struct("<HHI")  # type, compression, uncompressed size
_BG_GCODE, _BG_THUMBNAIL = 1, 5


class _Packed:
    """Shared behaviour of the packed sequences: equality with any sequence, short repr."""

    def __len__(self) -> int:  # pragma: no cover - overridden
        raise NotImplementedError

    def __iter__(self) -> Iterator[Any]:  # pragma: no cover - overridden
        raise NotImplementedError

    def __eq__(self, other: object) -> bool:
        if isinstance(other, (_Packed, tuple, list)):
            return len(self) == len(other) and all(
                a == b for a, b in zip(self, other, strict=True))
        return NotImplemented

    def __hash__(self) -> int:
        return hash(tuple(self))

    def __repr__(self) -> str:
        head = ", ".join(repr(v) for v in itertools.islice(self, 3))
        more = ", …" if len(self) > 3 else ""
        return f"{type(self).__name__}([{head}{more}], {len(self)} items)"


class PackedTexts(_Packed, Sequence[str]):
    """Command texts stored as one UTF-8 buffer and end offsets.

    A tuple of millions of ``str`` costs about 70 bytes per command on top of
    the text; this costs 8. Items are decoded when asked for; slices give tuples.

    Parameters
    ----------
    blob
        The texts, one after the other.
    ends
        End offset of each text in ``blob`` (the start is the previous end).
    """

    __slots__ = ("_blob", "_ends")

    def __init__(self, blob: bytes | bytearray, ends: array) -> None:
        self._blob = blob  # kept as given: a copy of a bytearray would double it for a moment
        self._ends = ends

    def __len__(self) -> int:
        return len(self._ends)

    def _span(self, i: int) -> tuple[int, int]:
        return (self._ends[i - 1] if i else 0), self._ends[i]

    @overload
    def __getitem__(self, index: int) -> str: ...

    @overload
    def __getitem__(self, index: slice) -> tuple[str, ...]: ...

    def __getitem__(self, index: int | slice) -> str | tuple[str, ...]:
        if isinstance(index, slice):
            return tuple(self[i] for i in range(*index.indices(len(self))))
        n = len(self._ends)
        if index < 0:
            index += n
        if not 0 <= index < n:
            raise IndexError("command index out of range")
        a, b = self._span(index)
        return self._blob[a:b].decode("utf-8")

    def __iter__(self) -> Iterator[str]:
        blob = self._blob
        a = 0
        for b in self._ends:
            yield blob[a:b].decode("utf-8")
            a = b

    def sizes(self) -> Iterator[int]:
        """Length of each text in bytes (UTF-8), without decoding."""
        a = 0
        for b in self._ends:
            yield b - a
            a = b


class PackedNumbers(_Packed, Sequence[Any]):
    """Numbers in an :class:`array.array` (8 bytes each, not a Python object each).

    Parameters
    ----------
    values
        The numbers (``array("q")`` for line numbers, ``array("d")`` for seconds).
    """

    __slots__ = ("_values",)

    def __init__(self, values: array) -> None:
        self._values = values

    def __len__(self) -> int:
        return len(self._values)

    @overload
    def __getitem__(self, index: int) -> Any: ...

    @overload
    def __getitem__(self, index: slice) -> tuple[Any, ...]: ...

    def __getitem__(self, index: int | slice) -> Any:
        if isinstance(index, slice):
            return tuple(self._values[index])
        return self._values[index]

    def __iter__(self) -> Iterator[Any]:
        return iter(self._values)


@dataclass(frozen=True)
class Program:
    """The commands of a G-code file, ready to send.

    Attributes
    ----------
    source
        Where the commands came from (path or description).
    commands
        The commands to send, in order: no comments, no blank lines, trimmed
        (a :class:`PackedTexts` when read from a file: a few bytes per command).
    source_lines
        1-based line of the file for each command.
    seconds
        Cumulative estimated motion time after each command, s (moves at
        their programmed feed rate, dwells; heating waits count 0).
    axes
        Axis letters used by moves (``G0``–``G3``, ``G92``), e.g. ``{"X", "Y", "Z", "E", "C"}``.
    skipped
        Lines of the file that hold something but are not sent, with why
        (``M110``...), as ``(line, reason)``; the first thousand.
    """

    source: str
    commands: Sequence[str]
    source_lines: Sequence[int]
    seconds: Sequence[float]
    axes: frozenset[str]
    skipped: tuple[tuple[int, str], ...] = ()

    def __len__(self) -> int:
        return len(self.commands)

    @property
    def total_seconds(self) -> float:
        """Estimated motion time of the whole file, s."""
        return self.seconds[-1] if len(self.seconds) else 0.0

    @property
    def rotary_axes(self) -> frozenset[str]:
        """Extra axes the file drives (A, B, C, U, V, W)."""
        return self.axes & EXTRA_AXES

    def where(self, index: int) -> str:
        """``"command 12 (file line 40: G1 X1)"`` for a 0-based command index."""
        if not 0 <= index < len(self.commands):
            return f"command {index + 1} (past the end)"
        text = self.commands[index]
        if len(text) > 60:
            text = text[:60] + "…"
        return (f"command {index + 1} of {len(self.commands)} "
                f"({self.source} line {self.source_lines[index]}: {text})")


def _decode(raw: bytes, source: str, lineno: int) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{source}: line {lineno} is not valid UTF-8 (byte 0x{raw[exc.start]:02x} at column "
            f"{exc.start + 1}); nothing was sent. A printer receives text: re-export the file "
            f"from the slicer or remove the stray bytes."
        ) from None


class _Builder:
    """Turns the lines of a G-code file into a :class:`Program`, one line at a time, keeping
    only the packed commands (see :func:`parse_program` for the rules)."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.blob = bytearray()
        self.ends = array("q")
        self.lines = array("q")
        self.seconds = array("d")
        self.skipped: list[tuple[int, str]] = []
        self.estimate = _Estimator()

    def add(self, lineno: int, raw: bytes) -> None:
        cut = raw.find(b";")
        body = (raw if cut < 0 else raw[:cut]).strip()
        if not body:
            return
        text = _decode(body, self.source, lineno)
        if text[0] in "Nn":
            m = _FRAMED.match(text)
            if m and m.group(1):
                text = m.group(1)
                body = text.encode()
            elif m:
                return
        if "*" in text:
            raise InputError(
                f"{self.source}: line {lineno} contains '*' at column {text.index('*') + 1}, "
                f"which the Marlin protocol reserves for the checksum ({excerpt(text)}); "
                f"nothing was sent.")
        bad = _CONTROL.search(text)
        if bad:
            raise InputError(
                f"{self.source}: line {lineno} contains a control character "
                f"({excerpt(bad.group())} at column {bad.start() + 1}: "
                f"{excerpt(text[max(0, bad.start() - 20):])}); nothing was sent.")
        code = command_code(text)
        if code == "M110":
            if len(self.skipped) < _MAX_SKIPPED:
                self.skipped.append((lineno, "M110 not sent: the host numbers the lines itself"))
            return
        self.blob += body
        self.ends.append(len(self.blob))
        self.lines.append(lineno)
        self.seconds.append(self.estimate.add(text, code))

    def program(self) -> Program:
        if not self.ends:
            raise InputError(f"{self.source}: no G-code command to send (only comments or "
                             "blank lines)")
        return Program(self.source, PackedTexts(self.blob, self.ends), PackedNumbers(self.lines),
                       PackedNumbers(self.seconds), frozenset(self.estimate.axes),
                       tuple(self.skipped))


def _lines(fh: BinaryIO) -> Iterator[bytes]:
    """The lines of a file (ended by ``\\n``, ``\\r\\n`` or ``\\r``, as
    :meth:`bytes.splitlines`), read a megabyte at a time."""
    return _chunk_lines(iter(lambda: fh.read(_CHUNK), b""))


def _chunk_lines(chunks: Iterable[bytes]) -> Iterator[bytes]:
    """The lines of the text made of ``chunks`` (cut anywhere), as :func:`_lines`."""
    carry = bytearray()
    for chunk in chunks:
        if not chunk:
            continue
        # complete lines end at the last terminator; a final \r may be half of a \r\n
        cut = max(chunk.rfind(b"\n"), chunk.rfind(b"\r", 0, len(chunk) - 1))
        if cut < 0:
            carry += chunk
            continue
        if carry:
            carry += chunk[:cut + 1]
            yield from bytes(carry).splitlines()
        else:
            yield from chunk[:cut + 1].splitlines()
        carry = bytearray(chunk[cut + 1:])
    if carry:
        yield from bytes(carry).splitlines()


def parse_program(data: bytes, *, source: str = "<data>",
                  max_line_length: int | None = DEFAULT_MAX_LINE) -> Program:
    """Turn the bytes of a G-code file into a :class:`Program`.

    Parameters
    ----------
    data
        The whole file.
    source
        Name for messages.
    max_line_length
        Longest framed line the firmware accepts, bytes (Marlin's
        ``MAX_CMD_SIZE``, 96); longer commands are refused before anything is sent.
        None: not checked here (the host checks against the firmware it meets,
        :func:`check_line_lengths`).

    Raises
    ------
    InputError
        A command holds bytes that are not UTF-8, a ``*`` (reserved for the
        checksum) or a control character, or is too long once framed — all
        found before anything is sent, naming the line. Bytes that are not
        UTF-8 inside a comment are dropped with the comment.
    FileFormatError
        Binary G-code (``data`` starts with ``GCDE``) that is damaged: the one-paragraph
        message of :func:`gcode.bgcode.decode_bgcode`, naming the block.
    """
    if is_bgcode(data):
        texts = decode_bgcode(data, path=source).gcode_texts
        return _parse(_chunk_lines(texts), source, max_line_length)
    return _parse(_lines(io.BytesIO(data)), source, max_line_length)


def _parse(lines: Iterable[bytes], source: str, max_line_length: int | None) -> Program:
    builder = _Builder(source)
    for lineno, raw in enumerate(lines, start=1):
        builder.add(lineno, raw)
    program = builder.program()
    if max_line_length is not None:
        check_line_lengths(program, max_line_length)
    return program


def check_line_lengths(program: Program, max_line_length: int) -> None:
    """Refuse the program when a command, once numbered and checksummed, is longer than
    the firmware's line buffer (``max_line_length`` bytes): it would be cut there."""
    width = len(f"N{len(program.commands) + 10} *255\n")
    commands = program.commands
    sizes = (commands.sizes() if isinstance(commands, PackedTexts)
             else (len(text.encode()) for text in commands))
    for i, size in enumerate(sizes):
        if size + width > max_line_length:
            raise InputError(
                f"{program.source}: line {program.source_lines[i]} is {size + width} bytes "
                f"once numbered and checksummed, more than the firmware's {max_line_length}-byte "
                f"line buffer ({excerpt(commands[i], 40)}); nothing was sent.")


def program_memory(path: str | Path) -> int:
    """Bytes :func:`load_program` will keep for ``path``, at most (its text plus
    :data:`BYTES_PER_COMMAND` per line), from one quick pass that counts its lines.

    Binary G-code is compressed (and MeatPack-encoded): its size says little of its text.
    For it this is what decoding takes, from the block headers alone (nothing is
    decompressed): the file twice (its bytes and the blocks handed to the codec) and its
    G-code text twice (as decoded, then as bytes), the text being the G-code blocks'
    uncompressed size, times :data:`MEATPACK_EXPANSION` for MeatPack-encoded blocks (a
    bound). Once the file is decoded, :func:`load_program` checks the program itself:
    the text it holds plus the commands' text and :data:`BYTES_PER_COMMAND` per line.

    Raises
    ------
    PrintabilityOSError
        The file cannot be read.
    """
    path = Path(path)
    size = lines = 0
    try:
        with path.open("rb") as fh:
            if is_bgcode(fh.read(4)):
                return _binary_memory(fh)[0]
            fh.seek(0)
            while chunk := fh.read(_CHUNK):
                size += len(chunk)
                lines += chunk.count(b"\n") + chunk.count(b"\r")
    except OSError as exc:
        raise PrintabilityOSError(f"{path}: cannot read the G-code file "
                                  f"({exc.strerror or exc})") from None
    return size + BYTES_PER_COMMAND * (lines + 1)


def _binary_memory(fh: BinaryIO) -> tuple[int, int]:
    """What decoding the binary G-code file ``fh`` takes (see :func:`program_memory`) and
    the most text it decodes to, bytes."""
    size = os.fstat(fh.fileno()).st_size
    text = _binary_text_size(fh, size)
    return 2 * size + 2 * text, text


def _binary_text_size(fh: BinaryIO, size: int) -> int:
    """Most bytes of G-code text the binary G-code file ``fh`` (``size`` bytes) decodes to,
    from its block headers (libbgcode's framing, as :mod:`gcode.bgcode` reads it): each
    G-code block's uncompressed size, times :data:`MEATPACK_EXPANSION` when it is
    MeatPack-encoded. The walk stops where the framing is damaged (decoding then says
    what is wrong): what it found so far, or the file's size times the expansion when that
    is larger."""
    fh.seek(0)
    head = fh.read(_BG_HEADER.size)
    if len(head) < _BG_HEADER.size:
        return 0
    crc = 4 if _BG_HEADER.unpack(head)[2] == 1 else 0
    pos, total, complete = _BG_HEADER.size, 0, False
    while True:
        if pos == size:
            complete = True
            break
        fh.seek(pos)
        head = fh.read(_BG_BLOCK.size + 6)
        if len(head) < _BG_BLOCK.size + 2:
            break
        kind, compression, data_size = _BG_BLOCK.unpack_from(head)
        at = _BG_BLOCK.size
        stored = data_size
        if compression:
            if len(head) < at + 6:
                break
            stored = int.from_bytes(head[at:at + 4], "little")
            at += 4
        encoding = int.from_bytes(head[at:at + 2], "little")
        if kind == _BG_GCODE:
            total += data_size * (MEATPACK_EXPANSION if encoding else 1)
        pos += at + (6 if kind == _BG_THUMBNAIL else 2) + stored + crc
        if pos > size:
            break
    return total if complete else max(total, MEATPACK_EXPANSION * size)


def check_gcode_file(path: str | Path) -> None:
    """Refuse a G-code path that is missing or is not a regular file (``/dev/zero`` would
    be read for ever, a pipe consumed), before anything is read.

    Raises
    ------
    PrintabilityOSError
        Naming the file and what it is.
    """
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        raise PrintabilityOSError(f"{path}: cannot read the G-code file "
                                  f"({exc.strerror or exc}); nothing was sent.") from None
    if not stat.S_ISREG(mode):
        kind = "a folder" if stat.S_ISDIR(mode) else "a device, a pipe or a socket"
        raise PrintabilityOSError(f"{path}: cannot read the G-code file: it is {kind}, not a "
                                  f"regular file; nothing was sent.")


def load_program(path: str | Path, *,
                 max_line_length: int | None = DEFAULT_MAX_LINE,
                 max_memory: int | None = None) -> Program:
    """Read a G-code file into a :class:`Program` (see :func:`parse_program`).

    The file is read a megabyte at a time and only the commands are kept,
    packed (:class:`PackedTexts`): about the size of the file's commands plus
    :data:`BYTES_PER_COMMAND` bytes per command. Binary G-code (``.bgcode``, or any file
    starting with ``GCDE``) is read whole and decoded (:func:`gcode.bgcode.decode_bgcode`),
    then its G-code is read the same way; the memory it takes is checked before it is
    decoded (from its block headers, :func:`program_memory`) and again once it is.

    Parameters
    ----------
    path
        The G-code file: a regular file (a device such as ``/dev/zero``, a pipe
        or a folder is refused before anything is read).
    max_line_length
        See :func:`parse_program`.
    max_memory
        Most bytes the program may take (:func:`program_memory` estimates it
        before the file is parsed); default
        :func:`printability.settings.default_memory_limit`.

    Raises
    ------
    PrintabilityOSError
        The file cannot be read or is not a regular file.
    ResourceError
        The program would take more than ``max_memory``.
    InputError
        See :func:`parse_program`.
    FileFormatError
        Damaged binary G-code (a block that fails its CRC, a file cut off...): the
        one-paragraph message of :func:`gcode.bgcode.decode_bgcode`.
    """
    path = Path(path)
    check_gcode_file(path)
    if max_memory is None:
        from printability.base.settings import default_memory_limit

        max_memory = default_memory_limit()
    need = program_memory(path)
    try:
        with path.open("rb") as fh:
            head = fh.read(65536)
            binary = is_bgcode(head)
            if need > max_memory:
                text = _binary_memory(fh)[1] if binary else 0
                _too_big(path, need, max_memory, binary, text, decoded=False)
            if not binary:
                if b"\x00" in head:
                    raise InputError(f"{path}: this is a binary file, not G-code text; nothing "
                                     f"was sent.")
                fh.seek(0)
                return _parse(_lines(fh), str(path), max_line_length)
            fh.seek(0)
            data = fh.read()
    except OSError as exc:
        raise PrintabilityOSError(f"{path}: cannot read the G-code file "
                                  f"({exc.strerror or exc})") from None
    texts = decode_bgcode(data, path=str(path)).gcode_texts
    del data  # the decoded file (thumbnails, metadata) goes too: only its G-code is kept
    text = sum(map(len, texts))
    lines = sum(t.count(b"\n") + t.count(b"\r") for t in texts)
    need = 2 * text + BYTES_PER_COMMAND * (lines + 1)  # the text, the program
    if need > max_memory:
        _too_big(path, need, max_memory, binary, text, decoded=True)
    return _parse(_chunk_lines(texts), str(path), max_line_length)


def _too_big(path: Path, need: int, max_memory: int, binary: bool, text: int, *,
             decoded: bool) -> None:
    """Refuse a file whose program would take ``need`` bytes, more than ``max_memory``
    (binary G-code: ``text`` bytes of G-code, as decoded or at most)."""
    if not binary:
        raise ResourceError(
            f"{path}: reading this G-code file for streaming would take about "
            f"{need / 2**20:,.0f} MiB, more than the {max_memory / 2**20:,.0f} MiB allowed "
            f"(half the memory, at most 16 GiB); nothing was sent. Split the file (at a layer "
            f"change) and stream the parts with --resume-from, or use a host with more memory.")
    size = (f"its G-code is {text / 2**20:,.1f} MiB of text once decoded" if decoded else
            f"by its block headers, its G-code decodes to at most {text / 2**20:,.1f} MiB of "
            f"text")
    raise ResourceError(
        f"{path}: reading this binary G-code file for streaming would take about "
        f"{need / 2**20:,.0f} MiB ({size}), more than the {max_memory / 2**20:,.0f} MiB "
        f"allowed (half the memory, at most 16 GiB); nothing was sent. Export the part from "
        f"the slicer as text G-code, split it (at a layer change) and stream the parts with "
        f"--resume-from, or use a host with more memory.")


def _words(text: str) -> dict[str, float]:
    out: dict[str, float] = {}
    code_end = 0
    m = re.match(r"\s*[GMTgmt]\d+(?:\.\d+)?", text)
    if m:
        code_end = m.end()
    for letter, value in _WORD.findall(text[code_end:]):
        out[letter.upper()] = float(value)
    return out


@dataclass(frozen=True)
class MachineState:
    """Modal state of the firmware after some line of a program.

    Attributes
    ----------
    position
        Logical position of each axis (X, Y, Z, rotary axes, E), mm or degrees,
        in the file's coordinates (after any G92 it issued).
    absolute
        G90 (True) or G91 (False) for X, Y, Z and rotary axes.
    e_absolute
        M82 (True) or M83 (False).
    feed
        Last F, mm/min (None before any).
    temperatures
        Last targets set: ``{"T": 210.0, "B": 60.0}``, °C.
    fan
        Last part-fan speed 0–255 (M106/M107), None before any.
    inches
        G20 in effect.
    tool
        Active tool number.
    """

    position: dict[str, float] = field(default_factory=dict)
    absolute: bool = True
    e_absolute: bool = True
    feed: float | None = None
    temperatures: dict[str, float] = field(default_factory=dict)
    fan: int | None = None
    inches: bool = False
    tool: int = 0

    def apply(self, command: str) -> MachineState:
        """The state after ``command`` (a new object; this one is unchanged)."""
        code = command_code(command)
        if not code:
            return self
        if code in ("G0", "G1", "G2", "G3", "G92"):
            words = _words(command)
            pos = dict(self.position)
            for letter, value in words.items():
                if letter in "FIJKRPS":
                    continue
                if code == "G92":
                    pos[letter] = value
                elif letter == "E":
                    pos["E"] = value if self.e_absolute else pos.get("E", 0.0) + value
                elif letter in "XYZ" or letter in EXTRA_AXES:
                    pos[letter] = value if self.absolute else pos.get(letter, 0.0) + value
            if code == "G92" and not words:
                pos = {k: 0.0 for k in pos} | {k: 0.0 for k in "XYZE"}
            feed = words.get("F", self.feed) if code != "G92" else self.feed
            return replace(self, position=pos, feed=feed)
        if code == "G90":
            return replace(self, absolute=True, e_absolute=True)
        if code == "G91":
            return replace(self, absolute=False, e_absolute=False)
        if code == "M82":
            return replace(self, e_absolute=True)
        if code == "M83":
            return replace(self, e_absolute=False)
        if code in ("G20", "G21"):
            return replace(self, inches=code == "G20")
        if code in _HEATING_SETS or code in _HEATING_WAITS:
            words = _words(command)
            target = words.get("S", words.get("R"))
            if target is None:
                return self
            key = _HEATING_SETS.get(code) or _HEATING_WAITS[code]
            if key == "T" and "T" in words:
                key = f"T{int(words['T'])}"
            return replace(self, temperatures=self.temperatures | {key: target})
        if code == "M106":
            return replace(self, fan=int(_words(command).get("S", 255)))
        if code == "M107":
            return replace(self, fan=0)
        if code[0] == "T" and code[1:].isdigit():
            return replace(self, tool=int(code[1:]))
        return self


def state_at(program: Program, index: int) -> MachineState:
    """The modal state after the first ``index`` commands of ``program`` have run."""
    state = MachineState()
    for command in itertools.islice(program.commands, index):
        state = state.apply(command)
    return state


def restore_commands(state: MachineState, *, home_xy: bool, lift: float = 2.0,
                     travel_feed: float = 3000.0) -> tuple[str, ...]:
    """Commands that bring a freshly restarted printer back to ``state``.

    Heats (set both, then wait, so bed and hotend heat together), declares Z,
    the rotary angle and E where they were (the part is on the bed: Z cannot
    be homed; a nozzle turned by a stepper keeps its angle through a reset),
    lifts, homes X and Y if asked, travels back, lowers, then restores the
    modes and the feed rate.

    Parameters
    ----------
    state
        The state to restore (see :func:`state_at`).
    home_xy
        Home X and Y first (the firmware restarted and lost its position).
    lift
        Z clearance for the travel back, mm.
    travel_feed
        Travel feed rate, mm/min.
    """
    out: list[str] = []
    temps = state.temperatures
    for key, value in temps.items():
        if key == "B":
            out.append(f"M140 S{value:g}")
        elif key == "C":
            out.append(f"M141 S{value:g}")
        else:
            out.append(f"M104 {'' if key == 'T' else 'T' + key[1:] + ' '}S{value:g}")
    if "B" in temps:  # the bed is slowest: wait for it first
        out.append(f"M190 S{temps['B']:g}")
    for key, value in temps.items():
        if key[0] == "T":
            out.append(f"M109 {'' if key == 'T' else 'T' + key[1:] + ' '}S{value:g}")
    if state.inches:
        out.append("G20")
    pos = state.position
    out.append("G90")
    declare = [f"{k}{pos[k]:.4f}" for k in ("Z", *sorted(EXTRA_AXES)) if k in pos]
    if declare:
        out.append("G92 " + " ".join(declare))
    if "Z" in pos:
        out.append(f"G1 Z{pos['Z'] + lift:.4f} F600")
    if home_xy:
        out.append("G28 X Y")
    xy = [f"{k}{pos[k]:.4f}" for k in ("X", "Y") if k in pos]
    if xy:
        out.append(f"G1 {' '.join(xy)} F{travel_feed:g}")
    if "Z" in pos:
        out.append(f"G1 Z{pos['Z']:.4f} F600")
    out.append(f"G92 E{pos.get('E', 0.0):.5f}")
    out.append("M82" if state.e_absolute else "M83")
    if not state.absolute:
        out.append("G91")
    if state.fan is not None:
        out.append(f"M106 S{state.fan}")
    if state.feed is not None:
        out.append(f"G1 F{state.feed:g}")
    return tuple(out)


class _Estimator:
    """Cumulative motion time (s) after each command, and the axis letters moves use,
    one command at a time.

    Each move takes its path length over its feed rate (no acceleration: a
    lower bound that the host rescales by the observed pace); rotary-only
    moves count their angle as length, like a firmware that treats all axes
    as Euclidean would.
    """

    def __init__(self) -> None:
        self.pos: dict[str, float] = {"E": 0.0}  # X, Y, Z unknown until a move names them
        self.absolute = self.e_abs = True
        self.feed = 1500.0  # mm/min until the file sets one
        self.inch = 1.0
        self.total = 0.0
        self.axes: set[str] = set()

    def add(self, command: str, code: str) -> float:
        """Account for ``command`` (whose :func:`command_code` is ``code``); returns the
        total so far, s."""
        pos, inch = self.pos, self.inch
        if code in ("G0", "G1", "G2", "G3"):
            words = _words(command)
            if "F" in words and words["F"] > 0:
                self.feed = words["F"] * inch
            dist2 = de = 0.0
            for letter, value in words.items():
                if letter in "FIJKRPS":
                    continue
                self.axes.add(letter)
                value *= inch
                if letter == "E":
                    new = value if self.e_abs else pos.get("E", 0.0) + value
                    de = new - pos.get("E", new)
                else:
                    new = value if self.absolute else pos.get(letter, 0.0) + value
                    d = new - pos.get(letter, new)
                    dist2 += d * d
                pos[letter] = new
            # An E-only move (retraction) takes its filament length over F.
            self.total += (math.sqrt(dist2) or abs(de)) / self.feed * 60.0
        elif code == "G92":
            for letter, value in _words(command).items():
                self.axes.add(letter)
                pos[letter] = value * inch
        elif code == "G90":
            self.absolute = self.e_abs = True
        elif code == "G91":
            self.absolute = self.e_abs = False
        elif code == "M82":
            self.e_abs = True
        elif code == "M83":
            self.e_abs = False
        elif code == "G20":
            self.inch = 25.4
        elif code == "G21":
            self.inch = 1.0
        elif code == "G4":
            words = _words(command)
            self.total += words.get("S", 0.0) + words.get("P", 0.0) / 1000.0
        return self.total


def _estimate(commands: Iterable[str]) -> tuple[list[float], set[str]]:
    """Cumulative motion time (s) after each command, and the axis letters moves use
    (see :class:`_Estimator`)."""
    est = _Estimator()
    out = [est.add(command, command_code(command)) for command in commands]
    return out, est.axes


def executed_as_streamed(executed: list[str], commands: list[str],
                         report: StreamReport) -> bool:
    """Whether the firmware ran exactly ``commands`` once each, in order, with the host's
    own commands (``report.injected``) where it put them.

    One ambiguity is allowed, the one no host can resolve: commands sent but not
    acknowledged when the firmware restarted (``report.in_doubt``) are sent again
    after it, so some of them may also appear once just before the restart.
    """
    doubt = dict(report.in_doubt)
    expected: list[tuple[str, list[str]]] = []  # ("fixed" | "maybe", commands)
    cut = 0
    for at, cmds in report.injected:
        expected.append(("fixed", commands[cut:at]))
        if at in doubt:
            expected.append(("maybe", commands[at:at + doubt.pop(at)]))
        expected.append(("fixed", list(cmds)))
        cut = at
    expected.append(("fixed", commands[cut:]))
    pos = 0
    for kind, part in expected:
        if kind == "maybe":
            j = 0
            while j < len(part) and pos + j < len(executed) and executed[pos + j] == part[j]:
                j += 1
            pos += j
        else:
            if executed[pos:pos + len(part)] != part:
                return False
            pos += len(part)
    return pos == len(executed)

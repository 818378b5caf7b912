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

The state tracker (:class:`MachineState`, :func:`state_at`, in
:mod:`machine_io.machine_state`) follows the modal state the firmware would
have after a given line — positions including the rotary axis and E,
absolute/relative modes, feed rate, temperatures, fan — so that a print can be
resumed after a lost connection. The commands are stored packed
(:mod:`machine_io.packed`).
"""

from __future__ import annotations

import io
import math
import os
import re
import stat
import struct
from array import array
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from gcode.bgcode import decode_bgcode, is_bgcode
from machine_io.machine_state import MachineState, command_words, restore_commands, state_at
from machine_io.packed import PackedNumbers, PackedTexts
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
_CONTROL = re.compile(r"[\x00-\x08\x0a-\x1f\x7f]")
# Marlin's MAX_CMD_SIZE: longer lines are cut by the firmware.
DEFAULT_MAX_LINE = 96
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
            words = command_words(command)
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
            for letter, value in command_words(command).items():
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
            words = command_words(command)
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

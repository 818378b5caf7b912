"""A G-code file made ready to stream: the commands to send, where each came from,
the machine state at any line and a motion-time estimate.

Comments and blank lines are not sent; a line already framed by another host
(``N12 G1 X1*34``) loses its old number and checksum (the host numbers lines
itself); ``M110`` (set line number) is not sent either, because the host owns
the numbering. Everything else is sent exactly as written, trimmed.

The state tracker (:class:`MachineState`, :func:`state_at`) follows the modal
state the firmware would have after a given line — positions including the
rotary axis and E, absolute/relative modes, feed rate, temperatures, fan — so
that a print can be resumed after a lost connection.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

from machine_io.protocol import EXTRA_AXES, command_code
from machine_io.session import StreamReport
from printability.errors import InputError, PrintabilityOSError

__all__ = [
    "MachineState",
    "Program",
    "check_line_lengths",
    "executed_as_streamed",
    "load_program",
    "parse_program",
    "restore_commands",
    "state_at",
]

_FRAMED = re.compile(r"^[Nn]\d+\s*(.*?)\s*(?:\*\d+)?$")
_WORD = re.compile(r"([A-Za-z])\s*([+-]?(?:\d+\.?\d*|\.\d+))")
# Marlin's MAX_CMD_SIZE: longer lines are cut by the firmware.
DEFAULT_MAX_LINE = 96
_HEATING_WAITS = {"M109": "T", "M190": "B", "M191": "C"}
_HEATING_SETS = {"M104": "T", "M140": "B", "M141": "C"}


@dataclass(frozen=True)
class Program:
    """The commands of a G-code file, ready to send.

    Attributes
    ----------
    source
        Where the commands came from (path or description).
    commands
        The commands to send, in order: no comments, no blank lines, trimmed.
    source_lines
        1-based line of the file for each command.
    seconds
        Cumulative estimated motion time after each command, s (moves at
        their programmed feed rate, dwells; heating waits count 0).
    axes
        Axis letters used by moves (``G0``–``G3``, ``G92``), e.g. ``{"X", "Y", "Z", "E", "C"}``.
    skipped
        Lines of the file that hold something but are not sent, with why
        (``M110``...), as ``(line, reason)``.
    """

    source: str
    commands: tuple[str, ...]
    source_lines: tuple[int, ...]
    seconds: tuple[float, ...]
    axes: frozenset[str]
    skipped: tuple[tuple[int, str], ...] = ()

    def __len__(self) -> int:
        return len(self.commands)

    @property
    def total_seconds(self) -> float:
        """Estimated motion time of the whole file, s."""
        return self.seconds[-1] if self.seconds else 0.0

    @property
    def rotary_axes(self) -> frozenset[str]:
        """Extra axes the file drives (A, B, C, U, V, W)."""
        return self.axes & EXTRA_AXES

    def where(self, index: int) -> str:
        """``"command 12 (file line 40: G1 X1)"`` for a 0-based command index."""
        if not 0 <= index < len(self.commands):
            return f"command {index + 1} (past the end)"
        return (f"command {index + 1} of {len(self.commands)} "
                f"({self.source} line {self.source_lines[index]}: {self.commands[index]})")


def _decode(raw: bytes, source: str, lineno: int) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{source}: line {lineno} is not valid UTF-8 (byte 0x{raw[exc.start]:02x} at column "
            f"{exc.start + 1}); nothing was sent. A printer receives text: re-export the file "
            f"from the slicer or remove the stray bytes."
        ) from None


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
    """
    commands: list[str] = []
    lines: list[int] = []
    skipped: list[tuple[int, str]] = []
    # Number of digits the largest line number will have: frame length check.
    for lineno, raw in enumerate(data.splitlines(), start=1):
        cut = raw.find(b";")
        body = raw if cut < 0 else raw[:cut]
        body = body.strip()
        if not body:
            continue
        text = _decode(body, source, lineno)
        if text[0] in "Nn":
            m = _FRAMED.match(text)
            if m and m.group(1):
                text = m.group(1)
            elif m:
                continue
        if "*" in text:
            raise InputError(
                f"{source}: line {lineno} contains '*', which the Marlin protocol reserves for "
                f"the checksum ({text!r}); nothing was sent.")
        if any(ord(c) < 32 and c != "\t" for c in text) or "\x7f" in text:
            raise InputError(
                f"{source}: line {lineno} contains a control character ({text!r}); nothing was "
                f"sent.")
        code = command_code(text)
        if code == "M110":
            skipped.append((lineno, "M110 not sent: the host numbers the lines itself"))
            continue
        commands.append(text)
        lines.append(lineno)
    if not commands:
        raise InputError(f"{source}: no G-code command to send (only comments or blank lines)")
    seconds, axes = _estimate(commands)
    program = Program(source, tuple(commands), tuple(lines), tuple(seconds), frozenset(axes),
                      tuple(skipped))
    if max_line_length is not None:
        check_line_lengths(program, max_line_length)
    return program


def check_line_lengths(program: Program, max_line_length: int) -> None:
    """Refuse the program when a command, once numbered and checksummed, is longer than
    the firmware's line buffer (``max_line_length`` bytes): it would be cut there."""
    width = len(f"N{len(program.commands) + 10} *255\n")
    for text, lineno in zip(program.commands, program.source_lines, strict=True):
        size = len(text.encode()) + width
        if size > max_line_length:
            raise InputError(
                f"{program.source}: line {lineno} is {size} bytes once numbered and "
                f"checksummed, more than the firmware's {max_line_length}-byte line buffer "
                f"({text[:40]!r}…); nothing was sent.")


def load_program(path: str | Path, *,
                 max_line_length: int | None = DEFAULT_MAX_LINE) -> Program:
    """Read a G-code file into a :class:`Program` (see :func:`parse_program`).

    Raises
    ------
    PrintabilityOSError
        The file cannot be read.
    InputError
        See :func:`parse_program`.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise PrintabilityOSError(f"{path}: cannot read the G-code file ({exc.strerror})") from None
    if b"\x00" in data[:65536]:
        raise InputError(f"{path}: this is a binary file, not G-code text; nothing was sent.")
    return parse_program(data, source=str(path), max_line_length=max_line_length)


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
    for command in program.commands[:index]:
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


def _estimate(commands: Iterable[str]) -> tuple[list[float], set[str]]:
    """Cumulative motion time (s) after each command, and the axis letters moves use.

    Each move takes its path length over its feed rate (no acceleration: a
    lower bound that the host rescales by the observed pace); rotary-only
    moves count their angle as length, like a firmware that treats all axes
    as Euclidean would.
    """
    pos: dict[str, float] = {"E": 0.0}  # X, Y, Z unknown until the first move names them
    absolute = e_abs = True
    feed = 1500.0  # mm/min until the file sets one
    inch = 1.0
    total = 0.0
    out: list[float] = []
    axes: set[str] = set()
    for command in commands:
        code = command_code(command)
        if code in ("G0", "G1", "G2", "G3"):
            words = _words(command)
            if "F" in words and words["F"] > 0:
                feed = words["F"] * inch
            dist2 = de = 0.0
            for letter, value in words.items():
                if letter in "FIJKRPS":
                    continue
                axes.add(letter)
                value *= inch
                if letter == "E":
                    new = value if e_abs else pos.get("E", 0.0) + value
                    de = new - pos.get("E", new)
                else:
                    new = value if absolute else pos.get(letter, 0.0) + value
                    d = new - pos.get(letter, new)
                    dist2 += d * d
                pos[letter] = new
            # An E-only move (retraction) takes its filament length over F.
            total += (math.sqrt(dist2) or abs(de)) / feed * 60.0
        else:
            if code == "G92":
                for letter, value in _words(command).items():
                    axes.add(letter)
                    pos[letter] = value * inch
            elif code == "G90":
                absolute = e_abs = True
            elif code == "G91":
                absolute = e_abs = False
            elif code == "M82":
                e_abs = True
            elif code == "M83":
                e_abs = False
            elif code == "G20":
                inch = 25.4
            elif code == "G21":
                inch = 1.0
            elif code == "G4":
                words = _words(command)
                total += words.get("S", 0.0) + words.get("P", 0.0) / 1000.0
        out.append(total)
    return out, axes


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

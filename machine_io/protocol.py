"""The Marlin serial protocol as pure functions: framing lines, reading replies.

Nothing here touches a port; :mod:`machine_io.host` drives the state machine
and this module only turns bytes into facts and back.

Host to firmware, every line of a print is framed as ``N<n> <command>*<cs>``
where ``cs`` is the XOR of every byte before ``*`` (Marlin's checksum). The
firmware accepts line ``n`` only if it is the last line it accepted plus one;
otherwise it answers ``Error:…Last Line: <k>``, ``Resend: <k+1>`` and ``ok``.
That rule alone makes retransmission safe: a line already executed is never
executed again, so the host may always retransmit when in doubt.

Firmware to host, the replies this module recognises (see :class:`Reply`):

``ok``                      the firmware is ready for one more line; with ADVANCED_OK
                            ``ok N<n> P<planner free> B<buffer free>``
``Resend: <n>`` / ``rs <n>``  retransmit from line ``n``
``busy: <why>``             alive but busy (host keepalive)
``Error:<text>``            a protocol error (checksum, line number) or a firmware error
``T:… B:…``                 temperatures, alone or after ``ok``
``X:… Y:… Count …``         an M114 position report
``FIRMWARE_NAME:…``, ``Cap:<NAME>:<0|1>``  the M115 report
``start``                   the banner after a reset
``//action:<name>``         host action commands (pause, resume, cancel)
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

__all__ = [
    "EXTRA_AXES",
    "LONG_COMMANDS",
    "FirmwareInfo",
    "Reply",
    "checksum",
    "command_code",
    "frame",
    "is_protocol_error",
    "parse_firmware_info",
    "parse_position",
    "parse_reply",
    "parse_temperatures",
]

# Axis letters that name an extra (rotary) axis on a Marlin-like firmware
# (Marlin's AXIS4_NAME…AXIS9_NAME choices). I, J, K are not in this set: on G2/G3
# they are arc offsets.
EXTRA_AXES = frozenset("ABCUVW")

# Commands that may legitimately keep the firmware silent for a long time
# (homing, probing, heating waits, dwell, user waits, finishing moves).
LONG_COMMANDS = frozenset(
    {"G4", "G28", "G29", "G33", "G34", "G35", "G76", "M0", "M1", "M109", "M190", "M191",
     "M303", "M400", "M600", "M701", "M702", "M48", "M1002"}
)

_RESEND = re.compile(r"^(?:Resend:|rs)\s*N?:?\s*(\d+)", re.IGNORECASE)
_OK_WORDS = re.compile(r"\b([NPB])(\d+)")
_TEMP = re.compile(r"(?<![A-Za-z@])(T\d*|B|C):\s*(-?\d+(?:\.\d+)?)"
                   r"(?:\s*/\s*(-?\d+(?:\.\d+)?))?")
_POSITION = re.compile(r"(?<![A-Za-z])([XYZABCUVWE]):\s*(-?\d+(?:\.\d+)?)")
_CAP = re.compile(r"^Cap:([A-Z0-9_]+):\s*(\S+)")
_FW_KEY = re.compile(r"([A-Z_]+):")
# Marlin's protocol errors: the line was garbled or out of sequence and a
# Resend follows; none of them is a printer fault.
_PROTOCOL_ERRORS = ("checksum", "line number", "last line", "no line number",
                    "no checksum", "format error", "expected line")


def checksum(data: bytes) -> int:
    """XOR of all bytes (Marlin's line checksum), 0–255."""
    cs = 0
    for b in data:
        cs ^= b
    return cs


def frame(number: int, command: str) -> bytes:
    """``N<number> <command>*<checksum>\\n`` as bytes (UTF-8).

    Parameters
    ----------
    number
        The line number, ≥ 0.
    command
        One command without comment, line number or checksum.
    """
    body = f"N{number} {command}".encode()
    return b"%s*%d\n" % (body, checksum(body))


def command_code(command: str) -> str:
    """The command word, upper-cased and normalised: ``"g1 x1"`` → ``"G1"``, ``"G01"`` → ``"G1"``.

    Returns ``""`` for a line that does not start with G, M or T and a number
    (a named macro, for example).
    """
    s = command.lstrip()
    if len(s) < 2 or s[0] not in "GMTgmt":
        return ""
    i = 1
    while i < len(s) and (s[i].isdigit() or s[i] == "."):
        i += 1
    digits = s[1:i]
    if not digits:
        return ""
    if "." in digits:
        whole, _, frac = digits.partition(".")
        return f"{s[0].upper()}{int(whole or 0)}.{frac}"
    return f"{s[0].upper()}{int(digits)}"


def is_protocol_error(text: str) -> bool:
    """True if an ``Error:`` line reports a garbled or out-of-order line (a Resend follows)."""
    low = text.lower()
    return any(k in low for k in _PROTOCOL_ERRORS)


def parse_temperatures(text: str) -> dict[str, tuple[float, float | None]]:
    """Temperatures in a report: ``{"T": (actual, target), "B": (…)}``, °C.

    ``T``, ``T0``, ``T1``… are hotends, ``B`` the bed, ``C`` the chamber;
    power words (``@:``, ``B@:``) are skipped. Empty dict when none.
    """
    out: dict[str, tuple[float, float | None]] = {}
    for name, actual, target in _TEMP.findall(text):
        out[name] = (float(actual), float(target) if target else None)
    return out


def parse_position(text: str) -> dict[str, float] | None:
    """Axis positions of an M114 report (before ``Count``), or None if not one."""
    head = text.split("Count", 1)[0]
    pos = {k: float(v) for k, v in _POSITION.findall(head)}
    if "X" in pos and "Y" in pos:
        return pos
    return None


@dataclass(frozen=True, slots=True)
class Reply:
    """One line from the firmware, classified.

    Attributes
    ----------
    kind
        ``ok``, ``resend``, ``busy``, ``error``, ``start``, ``action``, ``temperature``,
        ``position``, ``firmware``, ``cap``, ``echo`` or ``other``.
    text
        The line without its terminator.
    number
        ``ok N<n>`` (ADVANCED_OK) or the line a ``Resend`` asks for.
    planner, buffer
        ADVANCED_OK free planner moves and free command slots.
    """

    kind: str
    text: str
    number: int | None = None
    planner: int | None = None
    buffer: int | None = None


_OK = Reply("ok", "ok")


def parse_reply(text: str) -> Reply:
    """Classify one firmware line (already decoded, terminator stripped)."""
    if text == "ok":  # the hot path: most replies of a print
        return _OK
    s = text.strip()
    low = s.lower()
    if low.startswith("ok"):
        if len(s) > 2 and s[2] not in " \t:":
            return Reply("other", s)
        n = p = b = None
        for letter, value in _OK_WORDS.findall(s[2:].split("T:", 1)[0]):
            if letter == "N":
                n = int(value)
            elif letter == "P":
                p = int(value)
            else:
                b = int(value)
        return Reply("ok", s, n, p, b)
    m = _RESEND.match(s)
    if m:
        return Reply("resend", s, int(m.group(1)))
    if low.startswith(("busy:", "echo:busy:")):
        return Reply("busy", s)
    if low.startswith("error:") or low.startswith("!!"):
        return Reply("error", s)
    if low == "start":
        return Reply("start", s)
    if low.startswith("//action:"):
        return Reply("action", s)
    if s.startswith("FIRMWARE_NAME:"):
        return Reply("firmware", s)
    if s.startswith("Cap:"):
        return Reply("cap", s)
    if "T:" in s and parse_temperatures(s):
        return Reply("temperature", s)
    if "Count" in s and parse_position(s) is not None:
        return Reply("position", s)
    if low.startswith("echo:"):
        return Reply("echo", s)
    return Reply("other", s)


@dataclass(frozen=True)
class FirmwareInfo:
    """What the firmware says about itself (M115, M114).

    Attributes
    ----------
    name
        ``FIRMWARE_NAME`` (e.g. ``"Marlin 2.1.2.1"``), ``""`` if not reported.
    fields
        Every ``KEY:value`` of the FIRMWARE_NAME line.
    capabilities
        ``Cap:NAME:value`` lines, value as written (``"1"``/``"0"`` usually).
    axes
        Axis letters the firmware reports in an M114 position report (E
        excluded); empty when unknown.
    """

    name: str = ""
    fields: MappingProxyType[str, str] = field(default_factory=lambda: MappingProxyType({}))
    capabilities: MappingProxyType[str, str] = field(
        default_factory=lambda: MappingProxyType({}))
    axes: frozenset[str] = frozenset()

    def cap(self, name: str) -> bool:
        """True if capability ``name`` is reported and enabled."""
        return self.capabilities.get(name, "0") not in ("0", "", "false", "no")

    @property
    def advanced_ok(self) -> bool:
        return self.cap("ADVANCED_OK")

    @property
    def busy_protocol(self) -> bool:
        """The firmware sends ``busy:`` while it works (Marlin's host keepalive)."""
        return any(self.cap(c) for c in ("BUSY_PROTOCOL", "HOST_KEEPALIVE", "BUSY"))

    @property
    def checks_line_numbers(self) -> bool:
        """The firmware checks line numbers and refuses a copy of a line it has run (Marlin,
        RepRapFirmware); Klipper strips numbers and checksums unread, so a copy would run
        twice."""
        return not self._reads_raw_lines

    @property
    def cuts_long_lines(self) -> bool:
        """The firmware cuts a line past its buffer (Marlin's MAX_CMD_SIZE, the host's
        ``max_line_length``); Klipper reads a whole line of any length from its
        pseudo-terminal."""
        return not self._reads_raw_lines

    @property
    def _reads_raw_lines(self) -> bool:
        # Klipper's host software, whose name M115 reports as FIRMWARE_NAME:Klipper
        return self.name.lower().startswith("klipper")

    @property
    def axis_count(self) -> int | None:
        """``AXIS_COUNT`` of M115 (Marlin 2.1 with extra axes), None if not reported."""
        m = re.match(r"\d+", self.fields.get("AXIS_COUNT", ""))
        return int(m.group()) if m else None

    def has_axis(self, letter: str) -> bool | None:
        """Whether the firmware drives axis ``letter``: True, False, or None when it does not say.

        M114's letters are authoritative; failing them, ``AXIS_COUNT`` ≤ 3 means
        no extra axis at all, and > 3 means extra axes whose letters are unknown.
        """
        if self.axes:
            return letter in self.axes
        count = self.axis_count
        if count is None:
            return None
        return None if count > 3 else False

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "fields": dict(self.fields),
                "capabilities": dict(self.capabilities), "axes": sorted(self.axes)}


def parse_firmware_info(lines: list[str], position: dict[str, float] | None = None
                        ) -> FirmwareInfo:
    """Build a :class:`FirmwareInfo` from the M115 reply lines and an optional M114 report.

    Parameters
    ----------
    lines
        Reply lines of M115 (``FIRMWARE_NAME:…`` and ``Cap:…``); others are skipped.
    position
        The parsed M114 report, which names the axes the firmware drives.
    """
    name = ""
    fields: dict[str, str] = {}
    caps: dict[str, str] = {}
    for line in lines:
        s = line.strip()
        m = _CAP.match(s)
        if m:
            caps[m.group(1)] = m.group(2)
            continue
        if s.startswith("FIRMWARE_NAME:"):
            keys = list(_FW_KEY.finditer(s))
            for i, k in enumerate(keys):
                end = keys[i + 1].start() if i + 1 < len(keys) else len(s)
                fields[k.group(1)] = s[k.end():end].strip()
            name = fields.get("FIRMWARE_NAME", "")
    axes = frozenset(k for k in position if k != "E") if position else frozenset()
    return FirmwareInfo(name, MappingProxyType(fields), MappingProxyType(caps), axes)

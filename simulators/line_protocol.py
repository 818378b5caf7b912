"""The firmware's side of the wire: receive ring, line reader, line numbers and checksums.

Bytes land in the receive ring (Marlin's emergency parser sees them on the
way), the reader cuts them into lines while the command queue has room, and
each line's number and checksum are checked before it is queued; a refused
line is answered with ``Error:…``, ``Resend:`` and ``ok``. Faults of the
fault plan act on received lines here. Also the link markers
(:class:`Stall`, :class:`Disconnect`) the firmware's output carries. Mixed
into :class:`simulators.firmware.Firmware`, whose docstring describes the
model.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from simulators.parsing import Command, parse_command

__all__ = ["Disconnect", "LineProtocolMixin", "Stall", "checksum"]

ERR_CHECKSUM = "checksum mismatch, Last Line: "
ERR_LINE_NO = "Line Number is not Last Line Number+1, Last Line: "
ERR_NO_CHECKSUM = "No Checksum with line number, Last Line: "
ERR_NO_LINE_NO = "No Line Number with checksum, Last Line: "

_EOL = re.compile(rb"[\r\n]")
_N_PREFIX = re.compile(r"N\s*(-?\d+)\s*")
_STRTOL = re.compile(r"\s*[+-]?\d+")
# Marlin's EMERGENCY_PARSER: "M112" alone on a line (after an optional line number) kills at
# once, even while the command queue is full.
_EMERGENCY = re.compile(rb"\s*(?:N\s*-?\d+\s*)?M112\s*(?:[*;].*)?$")
# ... and "M108" ends a heating wait (M109/M190) at once: how a host cancelling a print gets
# the printer out of a long heat-up to send it the cancel sequence.
_BREAK_WAIT = re.compile(rb"\s*(?:N\s*-?\d+\s*)?M108\s*(?:[*;].*)?$")


def checksum(data: bytes | str) -> int:
    """Marlin's line checksum: XOR of all bytes (before ``*``)."""
    if isinstance(data, str):
        data = data.encode("latin-1", "replace")
    c = 0
    for b in data:
        c ^= b
    return c


@dataclass(frozen=True)
class Stall:
    """Output marker: the link says nothing for ``seconds`` of real time."""

    seconds: float


@dataclass(frozen=True)
class Disconnect:
    """Output marker: the link drops (the board reset); transports reconnect."""


@dataclass
class Entry:
    n: int | None
    cmd: Command
    drop_ok: bool = False
    duplicate_ok: bool = False
    busy: int = 0
    corrupt_reply: bool = False


class LineProtocolMixin:
    """Receiving and reading lines for :class:`simulators.firmware.Firmware`."""

    def _arrivals(self) -> None:
        room = self.fw.rx_buffer - len(self._ring)
        while self._pending and self._pending[0][0] <= self.now and not self.halted:
            data = self._pending[0][1]
            off = self._pending_off  # consumed bytes of the head chunk (no O(n²) slicing)
            left = len(data) - off
            if left <= room:
                self._take(data[off:])
                room -= left
                self._pending.popleft()
                self._pending_off = 0
            elif self.fw.rx_overflow_drops:
                self._take(data[off:off + room])
                self.stats.bytes_dropped += left - room
                room = 0
                self._pending.popleft()
                self._pending_off = 0
            else:  # flow control holds the rest back
                if room > 0:
                    self._take(data[off:off + room])
                    self._pending_off = off + room
                break
            if self.halted:
                return

    def _take(self, data: bytes) -> None:
        """Bytes enter the receive ring; Marlin's emergency parser sees them on the way."""
        self._ring += data
        if not self.fw.emergency_parser:
            return
        start = 0
        while True:
            m = _EOL.search(data, start)
            piece = data[start:m.start() if m else len(data)]
            if len(self._ep_line) < 64:
                self._ep_line += piece[:64]
            if not m:
                return
            if _EMERGENCY.match(self._ep_line):
                self.executed.append((None, "M112"))
                self._kill()
                return
            if _BREAK_WAIT.match(self._ep_line):
                self._break_heating_wait()
            self._ep_line.clear()
            start = m.end()

    def _break_heating_wait(self) -> None:
        """M108 through the emergency parser: a heating wait in progress ends now (its
        command finishes and is acknowledged; the heater keeps its target)."""
        wait = getattr(self, "_wait", None)
        if wait is not None and wait[0] == "time" and len(wait) > 2 and wait[2] == "temp":
            self._wait = ("time", self.now)

    # ================================================================ reading
    def _read_lines(self) -> bool:
        progressed = False
        while len(self._queue) < self.fw.command_buffer and self._ring and not self.halted:
            m = _EOL.search(self._ring)
            end = m.start() if m else len(self._ring)
            chunk = self._ring[:end]
            del self._ring[:end + (1 if m else 0)]
            progressed = True
            if not self._in_comment:
                semi = chunk.find(b";")
                if semi >= 0:
                    chunk = chunk[:semi]
                    self._in_comment = True
                room = self.fw.max_line - 1 - len(self._line)
                if len(chunk) > room:
                    chunk = chunk[:max(room, 0)]
                self._line += chunk
            if m:
                line = bytes(self._line)
                self._line.clear()
                self._in_comment = False
                progressed = True
                if line.strip():
                    self._process_line(line)
            else:
                break
        return progressed

    def _line_error(self, err: str) -> None:
        self.stats.errors[err.split(",")[0]] = self.stats.errors.get(err.split(",")[0], 0) + 1
        self._emit(f"Error:{err}{self.last_n}")
        # Marlin empties the receive ring before asking for the resend.
        self._ring.clear()
        self._line.clear()
        self._in_comment = False
        while self._pending and self._pending[0][0] <= self.now:
            self._pending.popleft()
            self._pending_off = 0
        self._emit(f"Resend: {self.last_n + 1}")
        self.stats.resends += 1
        if self.fw.ok_after_resend:
            self._emit("ok")

    def _process_line(self, raw: bytes) -> None:
        text = raw.decode("latin-1").strip()
        if not text:
            return
        self.stats.lines_in += 1
        self._ordinal += 1
        n_match = _N_PREFIX.match(text)
        entry_flags: dict[str, Any] = {}
        if self.config.faults.faults:
            key = int(n_match.group(1)) if n_match else self._ordinal
            for f in self.faults.draw(key):
                self.stats.faults.append((f.kind, key))
                if f.kind == "drop-line":
                    return
                if f.kind == "corrupt":
                    text = self.faults.corrupt(text.encode("latin-1")).decode("latin-1")
                    n_match = _N_PREFIX.match(text)
                elif f.kind == "resend-storm":
                    self._storm = max(self._storm, int(f.arg))
                elif f.kind == "stall":
                    self._mark(Stall(f.arg))
                elif f.kind == "disconnect":
                    self._mark(Disconnect())
                    self.stats.resets += 1
                    self._power_on(banner=False)
                    return
                elif f.kind == "drop-ok":
                    entry_flags["drop_ok"] = True
                elif f.kind == "duplicate-ok":
                    entry_flags["duplicate_ok"] = True
                elif f.kind == "busy":
                    entry_flags["busy"] = max(1, int(f.arg))
                elif f.kind == "corrupt-reply":
                    entry_flags["corrupt_reply"] = True
        n: int | None = None
        star = text.rfind("*")
        if self.fw.checksums:
            if n_match:
                npos = n_match
                if "M110" in text:
                    m2 = re.search(r"N\s*(-?\d+)", text[n_match.end():])
                    if m2 and text.find("M110") < n_match.end() + m2.start():
                        npos = m2
                n = int(npos.group(1))
                if n != self.last_n + 1 and "M110" not in text:
                    return self._line_error(ERR_LINE_NO)
                if star < 0:
                    return self._line_error(ERR_NO_CHECKSUM)
                # strtol(): leading digits count, anything after them is ignored, none is 0.
                m_sum = _STRTOL.match(text, star + 1)
                given = int(m_sum.group()) if m_sum else 0
                if given != checksum(text[:star]) or self._storm > 0:
                    self._storm = max(self._storm - 1, 0)
                    return self._line_error(ERR_CHECKSUM)
                self.last_n = n
                body = text[n_match.end():star]
            elif star >= 0:
                return self._line_error(ERR_NO_LINE_NO)
            else:
                body = text
        else:  # Klipper: line numbers and checksums are stripped, never checked
            if n_match:
                n = int(n_match.group(1))
            body = text[n_match.end() if n_match else 0:star if star >= 0 else len(text)]
        cmd = parse_command(body)
        if cmd.code == "M112":
            self.executed.append((n, cmd.text))
            self._kill()
            return
        self._queue.append(Entry(n, cmd, **entry_flags))


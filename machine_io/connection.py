"""The host's side of the link outside the stream: port, banner, handshake, queries.

Opening and closing the port, waiting for the ``start`` banner, the ``M110``
line-number handshake, unnumbered queries (``M115``, ``M114``), reading and
writing lines through the transcript, and event notes. Mixed into
:class:`machine_io.host.Host`, whose docstring states the protocol's promises.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator

from machine_io.protocol import (
    FirmwareInfo,
    Reply,
    frame,
    parse_firmware_info,
    parse_position,
    parse_reply,
    parse_temperatures,
)
from machine_io.transport import LineReader, open_port
from printability.base.errors import PrinterError, excerpt

__all__ = ["ConnectionMixin"]

_HINT = ("A board that restarts in a loop (its power supply, a crashing firmware) or a baud "
         "rate that does not match its firmware's sends lines that are never an answer; "
         "check both (the baud rate now is ")


class Heard:
    """What the printer said while connecting: how many lines, how many ``start``
    banners, the last line (for the messages)."""

    def __init__(self) -> None:
        self.t0 = time.monotonic()
        self.lines = 0
        self.starts = 0
        self.last = ""

    def add(self, text: str) -> None:
        self.lines += 1
        if text.lower() == "start":
            self.starts += 1
        self.last = text

    def summary(self) -> str:
        """``"; it sent 812 lines in 60 s, none an answer (…); the last: 'echo:…'"``."""
        if not self.lines:
            return "; it sent nothing"
        restarts = (f", {self.starts} of them 'start' (it restarted {self.starts} times)"
                    if self.starts > 1 else "")
        return (f"; it sent {self.lines} line(s) in {time.monotonic() - self.t0:.0f} s"
                f"{restarts}, the last {excerpt(self.last)}")



class ConnectionMixin:
    """Port, banner, handshake and queries of :class:`machine_io.host.Host`."""

    # ----------------------------------------------------------------- connection
    def open(self) -> None:
        """Open the port (see :func:`machine_io.transport.open_port`)."""
        self._port = open_port(self.port_name, baud=self.config.baud)
        self._reader = LineReader(self._port)

    def close(self) -> None:
        """Close the port and the transcript."""
        if self._port is not None:
            with contextlib.suppress(Exception):
                self._port.close()
            self._port = None
        self.transcript.close()

    def connect(self) -> FirmwareInfo:
        """Open the port, wait for the banner, synchronise line numbers, read capabilities.

        All of it ends within ``config.connect_timeout`` seconds, however much the
        printer talks (a board in a reset loop, noise at a wrong baud rate).

        Returns
        -------
        FirmwareInfo
            Firmware name, capabilities (``Cap:`` lines) and axes (from M114).

        Raises
        ------
        PrintabilityOSError
            The port cannot be opened.
        PrinterError
            The printer does not answer the handshake, or the connection takes longer
            than ``config.connect_timeout``; the message says what it heard.
        """
        if self._port is None:
            self.open()
        with self._connecting():
            self._banner_seen = self._wait_banner(self.config.banner_timeout)
            self._handshake()
            m115 = self._query("M115", lambda r: r.kind in ("firmware", "cap"))
            m114 = self._query("M114", lambda r: r.kind == "position")
        position = None
        for line in m114:
            position = parse_position(line) or position
        self.firmware = parse_firmware_info(m115, position)
        self._note(f"connected to {self.firmware.name or 'an unnamed firmware'} on "
                   f"{self.port_name}" + (" (after its start banner)" if self._banner_seen else ""))
        return self.firmware

    @contextlib.contextmanager
    def _connecting(self) -> Iterator[None]:
        """Within the block every wait also ends at ``config.connect_timeout`` from now,
        and the lines received are counted for the messages."""
        self._connect_deadline = time.monotonic() + self.config.connect_timeout
        self._heard = Heard()
        try:
            yield
        finally:
            self._connect_deadline = None

    def _until(self, deadline: float) -> float:
        """``deadline``, or the connection's overall deadline if that comes first."""
        overall = self._connect_deadline
        return deadline if overall is None else min(deadline, overall)

    def _check_connect_deadline(self, doing: str) -> None:
        overall = self._connect_deadline
        if overall is None or time.monotonic() < overall:
            return
        raise PrinterError(
            f"the printer on {self.port_name} did not complete the connection within "
            f"{self.config.connect_timeout:g} s (--connect-timeout) while {doing}"
            f"{self._heard.summary()}; nothing of the file was sent. {_HINT}"
            f"{self.config.baud}).")

    def _write(self, data: bytes) -> None:
        self._reader.write(data)
        self._bytes_sent += len(data)

    def _readline(self, deadline: float) -> str | None:
        raw = self._reader.readline(deadline)
        if raw is None:
            return None
        text = raw.decode("utf-8", errors="replace").strip()
        self.transcript.write("Recv", text)
        if self._connect_deadline is not None:
            self._heard.add(text)
        return text

    def _replies(self, deadline: float) -> Iterator[Reply]:
        """The replies that arrive until ``deadline`` (or the connection's overall
        deadline), each parsed and observed.

        The deadline holds even for a board that never stops talking (the
        reader hands out complete lines without looking at the clock).
        """
        deadline = self._until(deadline)
        while time.monotonic() < deadline and (line := self._readline(deadline)) is not None:
            reply = parse_reply(line)
            self._observe(reply)
            yield reply

    def _wait_banner(self, timeout: float) -> bool:
        deadline = self._until(time.monotonic() + timeout)
        # A board in a boot loop or a noisy line never goes quiet: every wait has an end.
        while time.monotonic() < deadline:
            line = self._readline(deadline)
            if line is None:
                return False
            reply = parse_reply(line)
            if reply.kind == "start":
                # Drain the rest of the banner quickly (it arrives in one burst).
                end = self._until(time.monotonic() + max(1.0, timeout))
                quiet = time.monotonic() + 0.3
                while time.monotonic() < end and self._readline(min(quiet, end)) is not None:
                    quiet = time.monotonic() + 0.3
                return True
        return False

    def _handshake(self, number: int = 0) -> None:
        """``M110 N<number>``: the next line the firmware expects is ``number + 1``."""
        data = frame(number, f"M110 N{number}")
        # on its own (a new stream, a reconnection) the handshake is a connection too
        with self._connecting() if self._connect_deadline is None else contextlib.nullcontext():
            for attempt in range(1, self.config.handshake_attempts + 1):
                self._check_connect_deadline(f"waiting for the reply to 'M110 N{number}'")
                if self._handshake_attempt(data, number):
                    return
                self.transcript.write("Note", f"no ok to M110 (attempt {attempt})")
            self._check_connect_deadline(f"waiting for the reply to 'M110 N{number}'")
            heard = self._heard
        if heard.lines:
            raise PrinterError(
                f"the printer on {self.port_name} talked but never acknowledged 'M110 "
                f"N{number}' ({self.config.handshake_attempts} attempts of "
                f"{self.config.handshake_timeout:g} s{heard.summary()}); nothing of the "
                f"file was sent. {_HINT}{self.config.baud}).")
        raise PrinterError(
            f"the printer on {self.port_name} did not answer (no reply to 'M110 N{number}' "
            f"after {self.config.handshake_attempts} attempts of "
            f"{self.config.handshake_timeout:g} s); nothing of the file was sent. Check that it "
            f"is switched on, that the baud rate ({self.config.baud}) matches its firmware, "
            f"and that no other program holds the port.")

    def _handshake_attempt(self, data: bytes, number: int) -> bool:
        """Send the M110 once and wait for its ok; True when it came."""
        self.transcript.write("Send", data.decode().strip())
        self._write(data)
        refused = False
        for reply in self._replies(time.monotonic() + self.config.handshake_timeout):
            if reply.kind in ("error", "resend"):
                # The M110 itself was refused (damaged on the wire): the ok that
                # follows a Resend is not the handshake's.
                refused = True
                continue
            if reply.kind == "ok":
                # Let a late duplicate reply of an earlier attempt arrive and drop it.
                end = self._until(time.monotonic() + 1.0)
                quiet = time.monotonic() + 0.05
                while time.monotonic() < end and self._readline(min(quiet, end)) is not None:
                    quiet = time.monotonic() + 0.05
                return not (refused and reply.number != number)
            if reply.kind == "start":
                self._banner_seen = True
                return False  # it reset on the way: ask again
        return False

    def _query(self, command: str, wanted: Callable[[Reply], bool]) -> list[str]:
        """Send an unnumbered query, collect the wanted reply lines up to its ``ok``."""
        for _attempt in range(self.config.handshake_attempts):
            self._check_connect_deadline(f"waiting for the reply to '{command}'")
            self.transcript.write("Send", command)
            self._write(command.encode() + b"\n")
            got: list[str] = []
            deadline = time.monotonic() + self.config.handshake_timeout
            for reply in self._replies(deadline):
                if wanted(reply):
                    got.append(reply.text)
                elif reply.kind == "ok":
                    # Marlin puts the M114 report before the ok; some firmwares after it.
                    if got:
                        return got
                    got += [r.text for r in self._replies(time.monotonic() + 0.1) if wanted(r)]
                    # An ok and nothing else: the query may have been damaged on the wire
                    # (the firmware ran it as an unknown command); ask again.
                    break
            if got:
                return got
        return []

    def _observe(self, reply: Reply) -> None:
        """Facts any reply may carry (temperatures)."""
        if reply.kind in ("temperature", "ok") and "T:" in reply.text:
            temps = parse_temperatures(reply.text)
            if temps:
                self.temperatures = temps

    # ----------------------------------------------------------------- events
    def _note(self, message: str) -> None:
        self._events.append(message)
        self.transcript.write("Note", message)
        if self.on_event is not None:
            try:
                self.on_event(message)
            except (OSError, ValueError):
                # A display that can no longer write (a closed pipe, a terminal that hung up)
                # must not stop the host: the note may be the one before the cancel sequence.
                pass


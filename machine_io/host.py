"""The serial host: connect to a Marlin-like firmware and stream a program, losing nothing.

How it keeps its promise (every command of the file executed once, in order):

- Every line is numbered and checksummed (:func:`machine_io.protocol.frame`) and
  kept in a history by number. The firmware accepts line *n* only right after
  line *n − 1*, so a retransmitted line that already ran is refused, never run
  twice. The host therefore retransmits freely when in doubt (a timeout, a
  lost ``ok``) and always obeys the firmware's ``Resend: n``.
- A ``Resend`` caused by lines that were already on the wire when the first
  one came (send-ahead) is *stale*: it is recognised by the order of replies
  and ignored. Genuine requests for the same line are counted; past
  ``max_resends`` in a row the host stops and says where.
- The end of the file is only reached when the firmware has provably accepted
  the last line: ``ok N<last>`` with ADVANCED_OK, otherwise a numbered ``M105``
  barrier whose reply (``ok T:…``) cannot be confused with another ``ok``.
- Send-ahead keeps at most as many lines in flight as the firmware last
  reported free command slots (``ok … B<free>``) and never more bytes than its
  receive buffer holds; without such reports it is strict ping-pong.

Where the promise ends: a firmware *restart* (a board reset, a new ``start``
banner mid-print) forgets its line numbers and its planner. The host resumes
after the last acknowledged command, with the machine state restored. Two
things no host can know from the wire: moves the board had acknowledged but
not yet run are lost with its planner (the simulator's record lists them as
``lost_in_reset``), and commands sent but not yet acknowledged when it
restarted may have run before it; they are sent again and reported in
:attr:`StreamReport.in_doubt`.

One thread does everything (send, read, timers); :meth:`Host.pause`,
:meth:`Host.resume` and :meth:`Host.cancel` only set flags, so they may be
called from another thread or a signal handler. Ctrl-C while streaming
(SIGINT, when streaming runs in the main thread) is turned into a clean
cancel; a second Ctrl-C sends ``M112``.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import serial

from machine_io.program import Program, restore_commands, state_at
from machine_io.protocol import (
    LONG_COMMANDS,
    FirmwareInfo,
    Reply,
    command_code,
    frame,
    is_protocol_error,
    parse_firmware_info,
    parse_position,
    parse_reply,
    parse_temperatures,
)
from machine_io.session import (
    DEFAULT_CANCEL_GCODE,
    HostConfig,
    Progress,
    StreamReport,
    Transcript,
)
from machine_io.transport import LineReader, open_port
from printability.errors import InputError, PrinterError

__all__ = [
    "DEFAULT_CANCEL_GCODE",
    "Host",
    "HostConfig",
    "Progress",
    "StreamReport",
    "Transcript",
]

_BARRIER = "M105"
_DEFAULT_CONFIG = HostConfig()  # frozen: safe to share


@dataclass
class _Sent:
    """One transmission awaiting its reply."""

    number: int
    size: int
    seq: int
    long: bool


class _Stop(Exception):
    """Internal: unwind the streaming loop (the reason is in ``Host._stop_reason``)."""


def _atomic_json(path: Path, doc: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(doc, fh, indent=1)
        os.replace(tmp, path)
    except OSError:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


class Host:
    """A connection to one printer.

    Parameters
    ----------
    port
        Device, pty path or pyserial URL.
    config
        Protocol settings.
    transcript
        Where to log the conversation (None: nowhere).
    on_event
        Called with a one-line message for notable events (errors, resends,
        restarts), for display.

    Examples
    --------
    >>> with Host("printsim://") as host:            # doctest: +SKIP
    ...     host.connect()
    ...     report = host.stream(load_program("part.gcode"))
    """

    def __init__(self, port: str, *, config: HostConfig = _DEFAULT_CONFIG,
                 transcript: Transcript | None = None,
                 on_event: Callable[[str], None] | None = None) -> None:
        self.port_name = port
        self.config = config
        self.transcript = transcript or Transcript(None)
        self.on_event = on_event
        self.firmware = FirmwareInfo()
        self.temperatures: dict[str, tuple[float, float | None]] = {}
        self._port: Any = None
        self._reader: LineReader | None = None
        self._pause = threading.Event()
        self._cancel = threading.Event()
        self._emergency = threading.Event()
        self._events: list[str] = []
        self._banner_seen = False
        self.interrupted = False
        """True once Ctrl-C (SIGINT) cancelled a stream."""
        self._reset_counters()

    # ----------------------------------------------------------------- public control
    def pause(self) -> None:
        """Stop sending new lines after those in flight (thread-safe)."""
        self._pause.set()

    def resume(self) -> None:
        """Continue after :meth:`pause` (thread-safe)."""
        self._pause.clear()

    def cancel(self) -> None:
        """Stop sending, finish what is in flight, send the cancel sequence (thread-safe)."""
        self._cancel.set()

    def emergency_stop(self) -> None:
        """Send ``M112`` at the next opportunity and stop (thread-safe)."""
        self._emergency.set()
        self._cancel.set()

    @property
    def paused(self) -> bool:
        return self._pause.is_set()

    # ----------------------------------------------------------------- connection
    def __enter__(self) -> Host:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

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

        Returns
        -------
        FirmwareInfo
            Firmware name, capabilities (``Cap:`` lines) and axes (from M114).

        Raises
        ------
        PrintabilityOSError
            The port cannot be opened.
        PrinterError
            The printer does not answer the handshake.
        """
        if self._port is None:
            self.open()
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

    def _write(self, data: bytes) -> None:
        self._reader.write(data)
        self._bytes_sent += len(data)

    def _readline(self, deadline: float) -> str | None:
        raw = self._reader.readline(deadline)
        if raw is None:
            return None
        text = raw.decode("utf-8", errors="replace").strip()
        self.transcript.write("Recv", text)
        return text

    def _wait_banner(self, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while True:
            line = self._readline(deadline)
            if line is None:
                return False
            reply = parse_reply(line)
            if reply.kind == "start":
                # Drain the rest of the banner quickly (it arrives in one burst).
                quiet = time.monotonic() + 0.3
                while self._readline(quiet) is not None:
                    quiet = time.monotonic() + 0.3
                return True

    def _handshake(self, number: int = 0) -> None:
        """``M110 N<number>``: the next line the firmware expects is ``number + 1``."""
        data = frame(number, f"M110 N{number}")
        for attempt in range(1, self.config.handshake_attempts + 1):
            self.transcript.write("Send", data.decode().strip())
            self._write(data)
            deadline = time.monotonic() + self.config.handshake_timeout
            refused = False
            while True:
                line = self._readline(deadline)
                if line is None:
                    break
                reply = parse_reply(line)
                self._observe(reply)
                if reply.kind in ("error", "resend"):
                    # The M110 itself was refused (damaged on the wire): the ok that
                    # follows a Resend is not the handshake's.
                    refused = True
                    continue
                if reply.kind == "ok":
                    # Let a late duplicate reply of an earlier attempt arrive and drop it.
                    quiet = time.monotonic() + 0.05
                    while self._readline(quiet) is not None:
                        quiet = time.monotonic() + 0.05
                    if refused and reply.number != number:
                        break
                    return
                if reply.kind == "start":
                    self._banner_seen = True
                    break  # it reset on the way: ask again
            self.transcript.write("Note", f"{'M110 refused' if refused else 'no reply to M110'} "
                                          f"(attempt {attempt})")
        raise PrinterError(
            f"the printer on {self.port_name} did not answer (no reply to 'M110 N{number}' "
            f"after {self.config.handshake_attempts} attempts of "
            f"{self.config.handshake_timeout:g} s); nothing of the file was sent. Check that it "
            f"is switched on, that the baud rate ({self.config.baud}) matches its firmware, "
            f"and that no other program holds the port.")

    def _query(self, command: str, wanted: Callable[[Reply], bool]) -> list[str]:
        """Send an unnumbered query, collect the wanted reply lines up to its ``ok``."""
        for _attempt in range(self.config.handshake_attempts):
            self.transcript.write("Send", command)
            self._write(command.encode() + b"\n")
            got: list[str] = []
            deadline = time.monotonic() + self.config.handshake_timeout
            while True:
                line = self._readline(deadline)
                if line is None:
                    break
                reply = parse_reply(line)
                self._observe(reply)
                if wanted(reply):
                    got.append(reply.text)
                elif reply.kind == "ok":
                    # Marlin puts the M114 report before the ok; some firmwares after it.
                    if got:
                        return got
                    tail = time.monotonic() + 0.1
                    while (extra := self._readline(tail)) is not None:
                        r = parse_reply(extra)
                        self._observe(r)
                        if wanted(r):
                            got.append(r.text)
                    return got
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
            self.on_event(message)

    # ----------------------------------------------------------------- streaming
    def _reset_counters(self) -> None:
        self._frames: list[bytes] = [b""]  # index = line number; 0 is the handshake
        self._texts: list[str] = [""]
        self._owner: list[int] = [-1]
        self._next = 1
        self._max_sent = 0
        self._acked = 0
        self._acked_reliable = 0
        self._outstanding: deque[_Sent] = deque()
        self._out_bytes = 0
        self._seq = 0
        self._rewind_target = 0
        self._rewind_seq = 0
        self._resend_oks = 0
        self._resend_ok_deadline = 0.0
        self._last_genuine = 0
        self._genuine_count = 0
        self._report_buffer: int | None = None
        self._last_rx = time.monotonic()
        self._timeouts_in_row = 0
        self._lines_sent = 0
        self._resends = 0
        self._stale = 0
        self._timeouts = 0
        self._reconnects = 0
        self._bytes_sent = 0
        self._barrier_number = 0
        self._barrier_ok = False
        self._stop_reason: str | None = None
        self._injected: list[tuple[int, tuple[str, ...]]] = []
        self._in_doubt: list[tuple[int, int]] = []
        self._restarted = self._fatal = self._failed = False
        self._suspicious = 0
        self._error_kind: str | None = None
        self._deferred: tuple[int, float] | None = None
        self._quiet_until: float | None = None
        self._received = 0  # last line the firmware said it has (Error + Resend agreeing)
        self._error_last_line: int | None = None
        self._timeout_seq = -(10**9)
        self._cancel_done = False

    def _send_ahead(self) -> bool:
        mode = self.config.mode
        if mode == "ping-pong":
            return False
        return self.firmware.advanced_ok

    def _can_transmit(self, size: int) -> bool:
        if self._resend_oks:
            return False  # wait for the ok that goes with a Resend
        n_out = len(self._outstanding)
        if n_out == 0:
            return True
        if not self._send_ahead() or self._report_buffer is None:
            return False
        return (n_out < min(self._report_buffer, self.config.max_window)
                and self._out_bytes + size <= self.config.rx_buffer)

    def _append(self, text: str, owner: int) -> None:
        n = len(self._frames)
        self._frames.append(frame(n, text))
        self._texts.append(text)
        self._owner.append(owner)

    def _transmit(self, number: int) -> None:
        data = self._frames[number]
        self._seq += 1
        code = command_code(self._texts[number])
        self._outstanding.append(_Sent(number, len(data), self._seq, code in LONG_COMMANDS))
        self._out_bytes += len(data)
        self.transcript.write("Send", data[:-1].decode("utf-8", errors="replace"))
        self._write(data)
        self._lines_sent += 1
        if number > self._max_sent:
            self._max_sent = number
        self._next = number + 1

    def _pop_front(self) -> _Sent | None:
        if not self._outstanding:
            return None
        s = self._outstanding.popleft()
        self._out_bytes -= s.size
        return s

    def _set_acked(self, number: int, *, reliable: bool) -> None:
        if number > self._acked:
            self._acked = number
            if number >= self._last_genuine:
                self._genuine_count = 0
        if reliable and number > self._acked_reliable:
            self._acked_reliable = number
        self._timeouts_in_row = 0

    def _handle(self, reply: Reply, now: float) -> None:
        kind = reply.kind
        self._last_rx = now
        if kind == "ok":
            self._on_ok(reply)
        elif kind == "resend":
            self._on_resend(reply.number or 0, now)
        elif kind == "busy":
            pass  # alive: the clock was restarted above
        elif kind == "error":
            self._on_error(reply.text)
        elif kind == "start":
            self._on_restart()
        elif kind == "action":
            self._on_action(reply.text)
        elif kind == "temperature":
            self._observe(reply)
        elif kind == "echo" and "unknown command" in reply.text.lower():
            self._note(f"firmware: {reply.text}")

    def _on_ok(self, reply: Reply) -> None:
        if reply.buffer is not None:
            self._report_buffer = reply.buffer
        text = reply.text
        if "T:" in text:
            self._observe(reply)
            # Only M105 answers "ok T:…": the numbered barrier, accepted after every line.
            if self._barrier_number and self._max_sent >= self._barrier_number:
                self._barrier_ok = True
        if self._resend_oks and (reply.number is None or reply.number <= self._acked_reliable):
            self._resend_oks -= 1  # the ok that follows a Resend
            return
        n = reply.number
        if n is not None:
            # ADVANCED_OK names the line: duplicates and stale oks are recognised, and a
            # number never sent is a garbled reply.
            if n <= self._acked_reliable or n > self._max_sent:
                return
            if any(s.number <= n for s in self._outstanding):
                # Lines refused after an earlier error may sit behind newer transmissions.
                keep = deque(s for s in self._outstanding if s.number > n)
                self._out_bytes = sum(s.size for s in keep)
                self._outstanding = keep
            self._set_acked(n, reliable=True)
            return
        s = self._pop_front()
        if s is None:
            return  # an ok nobody waits for (a duplicate): nothing to free
        if not self.firmware.advanced_ok:
            self._set_acked(s.number, reliable=False)

    def _on_resend(self, number: int, now: float) -> None:
        self._resend_oks += 1
        self._resend_ok_deadline = now + self.config.resend_ok_timeout
        if number < 1 or number > self._max_sent + 1:
            self._note(f"ignored a resend request for line {number} (never sent)")
            return
        if number <= self._acked_reliable:
            # The firmware acknowledged that line: either the request is garbled or the
            # firmware lost its count (a restart we did not see). Retransmitting would run
            # lines twice in the second case, so do nothing: a firmware that kept its count
            # asks again for the right line at the next transmission.
            self._suspicious += 1
            if self._suspicious > self.config.max_resends:
                self._stop_reason = (
                    f"the firmware keeps asking for line {number} although it acknowledged "
                    f"line {self._acked_reliable}: it lost its line count (a restart without "
                    f"a start banner?)")
                self._failed = True
                raise _Stop
            self._note(f"ignored a resend request for line {number}, already acknowledged")
            return
        self._suspicious = 0
        order_error = self._error_kind == "line"
        self._error_kind = None
        if self._error_last_line == number - 1:
            # Error and Resend agree (a garbled reply would not): the firmware has every
            # line before the one it asks for.
            self._received = max(self._received, number - 1)
        self._error_last_line = None
        # Everything before the requested line has been accepted.
        while self._outstanding and self._outstanding[0].number < number:
            self._pop_front()
        self._set_acked(number - 1, reliable=False)
        pending = [s for s in self._outstanding if s.number == number]
        if order_error and pending:
            # A line out of sequence was refused while a transmission of the requested line
            # is unanswered. Marlin reads lines in the order sent, so: if the refused line was
            # sent before that transmission (a duplicate after a retransmission, or a line
            # behind an earlier refused one), that transmission is still on its way and
            # rewinding would put the host out of phase for good; if only later lines are
            # unanswered, the requested line was lost on the wire: rewind.
            # After a timeout, transmissions the host no longer tracks may still be answered
            # and the order tells nothing: wait a moment for the pending line's ok instead.
            newest = pending[-1].seq
            older = [s for s in self._outstanding if s.number > number and s.seq < newest]
            newer = [s for s in self._outstanding if s.number > number and s.seq > newest]
            ghosts = newest <= self._timeout_seq + 2 * self.config.max_window
            if older or not newer or ghosts:
                if older:
                    self._outstanding.remove(older[0])
                    self._out_bytes -= older[0].size
                elif ghosts and newer and self._deferred is None:
                    self._deferred = (number, now + self.config.confirm_timeout)
                self._stale += 1
                return
        # The first transmission from the requested line on is the one refused.
        victim = None
        for i, sent in enumerate(self._outstanding):
            if sent.number >= number:
                victim = sent
                del self._outstanding[i]
                self._out_bytes -= sent.size
                break
        if number == self._max_sent + 1:
            self._next = max(self._next, number)
            return  # a duplicate was refused; nothing to retransmit
        if (number == self._rewind_target and victim is not None
                and victim.seq < self._rewind_seq):
            self._stale += 1
            return  # refused because an earlier line was: already being retransmitted
        self._rewind(number)

    def _rewind(self, number: int) -> None:
        """Retransmit from line ``number`` (a genuine resend request)."""
        self._deferred = None
        if number == self._last_genuine:
            self._genuine_count += 1
        else:
            self._last_genuine, self._genuine_count = number, 1
        if self._genuine_count > self.config.max_resends:
            self._stop_reason = (
                f"the firmware asked for line {number} {self._genuine_count} times in a row "
                f"(limit {self.config.max_resends}): the link is too noisy or the baud rate is "
                f"wrong")
            self._failed = True
            raise _Stop
        self._resends += 1
        self._rewind_target = number
        self._rewind_seq = self._seq + 1
        self._next = number

    def _on_error(self, text: str) -> None:
        if is_protocol_error(text):
            low = text.lower()
            # "Line Number is not Last Line Number+1": a line out of sequence was refused.
            self._error_kind = ("line" if "line number is not" in low or "expected line" in low
                                else "checksum")
            m = re.search(r"last line:?\s*(\d+)", low)
            self._error_last_line = int(m.group(1)) if m else None
            return  # a Resend follows
        low = text.lower()
        fatal = "halted" in low or "kill" in low or "stopped" in low or text.startswith("!!")
        self._note(f"firmware error: {text}")
        if fatal:
            self._stop_reason = f"the printer halted ({text}); it needs a reset"
            self._fatal = self._failed = True
            raise _Stop
        policy = self.config.error_policy
        if policy == "ignore":
            return
        self._failed = True
        self._stop_reason = f"firmware error {text!r} (error policy '{policy}')"
        if policy == "stop":
            self._emergency.set()
        self._cancel.set()

    def _on_restart(self) -> None:
        self._banner_seen = True
        if self._max_sent:
            self._restarted = True
            raise _Stop

    def _on_action(self, text: str) -> None:
        action = text.split(":", 1)[1].strip().split()[0].lower() if ":" in text else ""
        if action in ("pause", "paused"):
            self._note("the printer asked to pause")
            self.pause()
        elif action in ("resume", "resumed"):
            self._note("the printer asked to resume")
            self.resume()
        elif action == "cancel":
            self._note("the printer asked to cancel")
            self.cancel()

    def _on_silence(self, now: float) -> None:
        """Nothing heard for the timeout: retransmit from the first unacknowledged line."""
        self._timeouts += 1
        self._timeouts_in_row += 1
        first = self._acked + 1
        if self._timeouts_in_row > self.config.max_timeouts:
            self._stop_reason = (
                f"the printer stopped answering (no reply for "
                f"{self._timeouts_in_row} × {self._current_timeout():g} s)")
            self._failed = True
            raise _Stop
        self.transcript.write("Note", f"timeout: retransmitting from line {first}")
        self._timeout_seq = self._seq
        self._outstanding.clear()
        self._out_bytes = 0
        self._resend_oks = 0
        self._rewind_target = first
        self._rewind_seq = self._seq + 1
        self._next = min(self._next, first)

    def _current_timeout(self) -> float:
        if any(s.long for s in self._outstanding):
            return self.config.long_timeout
        return self.config.reply_timeout

    def _take_waiting(self) -> None:
        """Handle every reply already received, before transmitting.

        A duplicated ``ok`` usually arrives right behind the first one; handled
        now, it finds nothing outstanding and is dropped, instead of being taken
        for the ``ok`` of the next line (which would let the host run ahead).
        """
        while self._reader.pending() or self._port.in_waiting:
            text = self._readline(0.0)
            if text is None:
                return
            self._handle(parse_reply(text), time.monotonic())

    def _pump_once(self, more: Callable[[], bool], allow_new: bool) -> None:
        """Transmit what the window allows, then handle at most a few replies."""
        self._take_waiting()
        now = time.monotonic()
        if self._deferred is not None:
            number, due = self._deferred
            if self._acked >= number:
                self._deferred = None
            elif now >= due:
                # The line a refusal asked for never got its ok: it was lost after all.
                for sent in list(self._outstanding):
                    if sent.number >= number:
                        self._outstanding.remove(sent)
                        self._out_bytes -= sent.size
                        break
                self._rewind(number)
        while self._next < len(self._frames) or (allow_new and more()):
            if not self._can_transmit(len(self._frames[self._next])):
                break
            self._transmit(self._next)
        now = time.monotonic()
        deadline = self._last_rx + self._current_timeout()
        if self._resend_oks:
            deadline = min(deadline, self._resend_ok_deadline)
        if self._deferred is not None:
            deadline = min(deadline, self._deferred[1])
        text = self._readline(min(deadline, now + 0.1))
        now = time.monotonic()
        if text is not None:
            self._handle(parse_reply(text), now)
            return
        if self._resend_oks and now >= self._resend_ok_deadline:
            # The firmware sent Resend without ok: do as if it had.
            self._resend_oks -= 1
            return
        if self._outstanding and now >= self._last_rx + self._current_timeout():
            self._on_silence(now)
            self._last_rx = now
        elif not self._outstanding:
            self._last_rx = now

    def stream(self, program: Program, *, start: int = 0, restore: bool = False,
               on_progress: Callable[[Progress], None] | None = None,
               resume_file: str | Path | None = None) -> StreamReport:
        """Send ``program`` from command ``start`` (0-based) to the end.

        Parameters
        ----------
        program
            The commands (see :func:`machine_io.program.load_program`).
        start
            First command to send; with ``restore`` the machine state the
            program would have reached there is restored first.
        restore
            Send :func:`machine_io.program.restore_commands` before ``start``.
        on_progress
            Called about ten times a second with a :class:`Progress`.
        resume_file
            JSON file kept up to date (atomically, every few seconds) with the
            next command to send, so a crashed session can be resumed.

        Returns
        -------
        StreamReport
            ``completed`` True when every command was acknowledged. A cancel
            (Ctrl-C, :meth:`cancel`, ``//action:cancel``) returns a report with
            ``stopped`` set.

        Raises
        ------
        PrinterError
            The printer failed or stopped answering, or lacks the rotary axis the
            program drives; the message says which command was the last
            acknowledged and how to resume. ``exc.report`` holds the report.
        """
        if self._port is None:
            self.connect()
        if not 0 <= start < len(program):
            raise InputError(f"start must be a command index in [0, {len(program) - 1}]; "
                             f"got {start}")
        self._check_axes(program)
        self._handshake(0)  # number this session's lines from 1
        if self._send_ahead() is False and self.config.mode == "send-ahead":
            self._note("send-ahead asked for, but the firmware does not report its buffer "
                       "(no ADVANCED_OK): streaming ping-pong")
        self._reset_counters()
        self._program = program
        self._cursor = start  # next program command to append to the history
        self._start = start
        mode = "send-ahead" if self._send_ahead() else "ping-pong"
        t0 = time.monotonic()
        self._t0 = t0
        if restore:
            self._inject(restore_commands(state_at(program, start),
                                          home_xy=self.config.home_on_restore), start)
        previous_handler = self._install_sigint()
        last_progress = 0.0
        last_save = t0
        resume_path = Path(resume_file) if resume_file is not None else None
        failure: str | None = None
        state = "streaming"
        try:
            while True:
                try:
                    if self._cancel.is_set():
                        state = "cancelling"
                        self._finish_cancel()
                        if self._failed:
                            failure = self._stop_reason
                        break
                    if self._pause.is_set():
                        state = "paused"
                        self._do_pause(on_progress)
                        state = "streaming"
                        continue
                    done = self._cursor >= len(program) and self._next >= len(self._frames)
                    if done and not self._outstanding:
                        if self._finished():
                            break
                        continue
                    self._pump_once(self._more, allow_new=True)
                except _Stop:
                    if self._restarted and not self._fatal:
                        # The firmware restarted under us (its banner came): same link.
                        if self._reconnect(reopen=False):
                            continue
                        self._failed = True
                    failure = self._stop_reason or "stopped"
                    break
                except (serial.SerialException, OSError) as exc:
                    self._note(f"the link failed: {exc}")
                    if self._reconnect(reopen=True):
                        continue
                    failure = f"the link to the printer failed ({exc}) and could not be reopened"
                    break
                now = time.monotonic()
                if on_progress is not None and now - last_progress >= 0.1:
                    last_progress = now
                    on_progress(self._progress(state))
                if resume_path is not None and now - last_save >= 2.0:
                    last_save = now
                    self._save_resume(resume_path)
        finally:
            self._restore_sigint(previous_handler)
        report = self._report(program, mode, time.monotonic() - t0, failure)
        if on_progress is not None:
            on_progress(self._progress("done"))
        if resume_path is not None:
            self._save_resume(resume_path)
        if failure is not None:
            exc = PrinterError(f"{failure}. {self._where(report)}")
            exc.report = report  # type: ignore[attr-defined]
            raise exc
        return report

    # -- helpers of stream()
    def _more(self) -> bool:
        """Append the next program command to the history; False at the end."""
        if self._cancel.is_set() or self._pause.is_set():
            return False
        if self._cursor >= len(self._program):
            return False
        self._append(self._program.commands[self._cursor], self._cursor)
        self._cursor += 1
        return True

    def _inject(self, commands: tuple[str, ...], before: int) -> None:
        if not commands:
            return
        for text in commands:
            self._append(text, -1)
        self._injected.append((before, tuple(commands)))

    def _program_acked(self) -> int:
        """Index of the next program command not yet acknowledged."""
        n = self._acked
        while n > 0 and self._owner[n] < 0:
            n -= 1
        return self._owner[n] + 1 if n > 0 else self._start

    def _finished(self) -> bool:
        """True once the firmware has provably accepted every line sent.

        Proofs: ``ok N<last>`` (ADVANCED_OK); a ``Resend`` for the line after the
        last, consistent with its ``Error:… Last Line``; or the reply of the
        numbered ``M105`` barrier (``ok T:…``), which no other ``ok`` resembles.
        A firmware whose M105 reply carries no temperatures gets a quiet
        moment (``confirm_timeout``) in which a late ``Resend`` would reopen
        the stream; after it, the stream ends.
        """
        if self._next < len(self._frames):
            self._pump_once(lambda: False, allow_new=False)
            return False
        proven = max(self._acked_reliable, self._received)
        if proven >= self._max_sent or self._barrier_ok:
            return True
        if (not self.firmware.advanced_ok and self.config.end_barrier
                and not self._barrier_number):
            self._inject((_BARRIER,), len(self._program))
            self._barrier_number = len(self._frames) - 1
            return False
        now = time.monotonic()
        if self._outstanding or self._next < len(self._frames):
            self._quiet_until = None
        elif self._quiet_until is None:
            self._quiet_until = now + self.config.confirm_timeout
        elif now >= self._quiet_until and self._acked >= self._max_sent:
            return True
        self._pump_once(lambda: False, allow_new=False)
        return False

    def _drain(self, timeout: float) -> None:
        """Let lines already sent be answered (retransmitting as asked), within ``timeout``."""
        end = time.monotonic() + timeout
        while (self._outstanding or self._next < len(self._frames)) and time.monotonic() < end:
            if self._emergency.is_set():
                return
            try:
                self._pump_once(lambda: False, allow_new=False)
            except _Stop:
                return

    def _finish_cancel(self) -> None:
        if self._emergency.is_set():
            self._send_emergency()
            if self._stop_reason is None:
                self._stop_reason = "emergency stop (M112)"
            return
        if self._stop_reason is None:
            self._stop_reason = "cancelled"
        self._trim_unsent()
        in_heating = any(command_code(self._texts[s.number]) in ("M109", "M190", "M191")
                         for s in self._outstanding)
        if in_heating:
            self._write(b"M108\n")  # Marlin's emergency parser breaks a heating wait
            self.transcript.write("Send", "M108")
        self._drain(self.config.reply_timeout * 2)
        if self._fatal:
            return
        before = self._program_acked()
        self._inject(self.config.cancel_gcode, before)
        # The cancel sequence is sent even though _cancel is set: it is not program text.
        self._drain(self.config.reply_timeout * 4)

    def _send_emergency(self) -> None:
        with contextlib.suppress(Exception):
            self._write(b"M112\n")
            self.transcript.write("Send", "M112")
        self._note("emergency stop: M112 sent")

    def _trim_unsent(self) -> None:
        """Forget program lines appended to the history but never transmitted."""
        k = self._max_sent + 1
        for n in range(k, len(self._frames)):
            if self._owner[n] >= 0:
                self._cursor = min(self._cursor, self._owner[n])
        del self._frames[k:]
        del self._texts[k:]
        del self._owner[k:]
        self._next = min(self._next, k)

    def _do_pause(self, on_progress: Callable[[Progress], None] | None) -> None:
        self._note("pausing: finishing the lines in flight")
        self._trim_unsent()
        self._drain(self.config.long_timeout)
        at = self._program_acked()
        state = state_at(self._program, at)
        self._inject(self.config.pause_gcode, at)
        self._drain(self.config.long_timeout)
        self._note(f"paused before {self._program.where(at)}")
        while self._pause.is_set() and not self._cancel.is_set():
            if on_progress is not None:
                on_progress(self._progress("paused"))
            text = self._readline(time.monotonic() + 0.2)
            if text is not None:
                reply = parse_reply(text)
                self._last_rx = time.monotonic()
                if reply.kind == "action":
                    self._on_action(reply.text)
                elif reply.kind == "temperature":
                    self._observe(reply)
                elif reply.kind == "start":
                    self._restarted = True
                    raise _Stop
        if self._cancel.is_set():
            return
        if self.config.pause_gcode:
            self._inject(restore_commands(state, home_xy=False), at)
        self._note("resumed")

    def _reopen(self, timeout: float) -> bool:
        """Close and reopen the same port object (a pyserial URL keeps its endpoint)."""
        end = time.monotonic() + timeout
        while True:
            try:
                with contextlib.suppress(Exception):
                    self._port.close()
                self._port.open()
                self._reader = LineReader(self._port)
                return True
            except (serial.SerialException, OSError, ValueError):
                if time.monotonic() >= end:
                    return False
                time.sleep(0.25)

    def _reconnect(self, *, reopen: bool) -> bool:
        """Resume after the link dropped (``reopen``) or the firmware restarted.

        Returns True when streaming can go on: the same firmware kept its line
        count (retransmit from the first unacknowledged line), or it restarted
        and its state was restored (temperatures, position, rotary angle, E).
        """
        timeout = self.config.reconnect_timeout
        if timeout <= 0:
            if self._stop_reason is None:
                self._stop_reason = ("the link was lost" if reopen else
                                     "the firmware restarted (start banner) in the middle of "
                                     "the print")
            return False
        self._reconnects += 1
        if reopen:
            self._note("the link was lost: reconnecting")
            if not self._reopen(timeout):
                self._stop_reason = (f"the link was lost and the port could not be reopened "
                                     f"within {timeout:g} s")
                return False
        restarted = self._restarted or self._wait_banner(self.config.banner_timeout)
        self._restarted = False
        self._timeouts_in_row = 0
        self._outstanding.clear()
        self._out_bytes = 0
        self._resend_oks = 0
        if not restarted:
            # Same firmware, same line count: retransmit from the first unacknowledged line;
            # the firmware refuses what it already has.
            self._next = self._acked + 1
            self._last_rx = time.monotonic()
            self._note("reconnected; the firmware kept its state")
            return True
        # The firmware restarted: what was not acknowledged may or may not have run; resume
        # from the first command not acknowledged, with the state restored.
        at = self._program_acked()
        unacked = [self._owner[n] for n in range(self._acked + 1, self._max_sent + 1)
                   if self._owner[n] >= 0]
        if unacked:
            self._in_doubt.append((unacked[0], len(unacked)))
            self._note(f"the firmware restarted with commands {unacked[0] + 1}–{unacked[-1] + 1} "
                       f"unacknowledged; resending them (any of them may have run before the "
                       f"restart)")
        else:
            self._note("the firmware restarted; every sent command had been acknowledged")
        try:
            self._handshake(self._max_sent)
        except PrinterError as exc:
            self._stop_reason = str(exc)
            return False
        # Rebuild the tail of the history: restore sequence, then the program from `at`.
        del self._frames[self._max_sent + 1:]
        del self._texts[self._max_sent + 1:]
        del self._owner[self._max_sent + 1:]
        self._acked = self._acked_reliable = self._max_sent
        self._cursor = at
        self._inject(restore_commands(state_at(self._program, at),
                                      home_xy=self.config.home_on_restore), at)
        self._next = self._max_sent + 1
        self._last_rx = time.monotonic()
        return True

    def _check_axes(self, program: Program) -> None:
        if not self.config.check_axes:
            return
        for letter in sorted(program.rotary_axes):
            has = self.firmware.has_axis(letter)
            if has:
                continue
            said = ("reports the axes " + ", ".join(sorted(self.firmware.axes))
                    if self.firmware.axes else
                    f"reports AXIS_COUNT:{self.firmware.axis_count}"
                    if self.firmware.axis_count is not None else
                    "does not report its axes (no M114 position report, no AXIS_COUNT)")
            raise PrinterError(
                f"{program.source} drives a rotary axis {letter} but the printer on "
                f"{self.port_name} ({self.firmware.name or 'unnamed firmware'}) {said}; "
                f"nothing was sent. Stream it to a T-T-R printer whose firmware has the axis "
                f"(Marlin 2.1 with AXIS4_NAME '{letter}'), or regenerate the G-code for this "
                f"machine; --no-axis-check overrides this check.")

    def _progress(self, state: str) -> Progress:
        done = self._program_acked()
        seconds = self._program.seconds
        return Progress(done, len(self._program), seconds[done - 1] if done else 0.0,
                        self._program.total_seconds, time.monotonic() - self._t0,
                        dict(self.temperatures), state, self._resends)

    def _report(self, program: Program, mode: str, elapsed: float,
                failure: str | None) -> StreamReport:
        acknowledged = self._program_acked()
        completed = failure is None and acknowledged >= len(program) and not self._cancel.is_set()
        stopped = None if completed else (failure or self._stop_reason or "stopped")
        return StreamReport(
            program.source, self.port_name, self.firmware, mode, len(program), self._start,
            acknowledged, completed, stopped, self._lines_sent, self._resends, self._stale,
            self._timeouts, self._reconnects, elapsed, self._bytes_sent,
            tuple(self._injected), tuple(self._events), dict(self.temperatures),
            tuple(self._in_doubt))

    def _where(self, report: StreamReport) -> str:
        program = self._program
        n = report.acknowledged
        in_flight = [self._owner[k] for k in range(self._acked + 1, self._max_sent + 1)
                     if self._owner[k] >= 0]
        if n == 0:
            text = "No command of the file was acknowledged"
        else:
            text = f"The last command acknowledged was {program.where(n - 1)}"
        if in_flight:
            text += (f"; commands {in_flight[0] + 1}–{in_flight[-1] + 1} were sent but not "
                     f"acknowledged and may or may not have run")
        if n < len(program):
            text += (f". To resume: printability stream {program.source} --port "
                     f"{self.port_name} --resume-from {program.source_lines[n]}")
        return text

    def _save_resume(self, path: Path) -> None:
        at = self._program_acked()
        doc = {"source": self._program.source, "port": self.port_name,
               "next_command": at,
               "next_line": self._program.source_lines[at] if at < len(self._program) else None,
               "total": len(self._program)}
        with contextlib.suppress(OSError):
            _atomic_json(path, doc)

    def _install_sigint(self) -> Any:
        if threading.current_thread() is not threading.main_thread():
            return None

        def handler(signum: int, frame_: Any) -> None:
            self.interrupted = True
            if self._cancel.is_set():
                self._emergency.set()
            self._cancel.set()

        try:
            return signal.signal(signal.SIGINT, handler)
        except ValueError:
            return None

    @staticmethod
    def _restore_sigint(previous: Any) -> None:
        if previous is not None:
            with contextlib.suppress(ValueError):
                signal.signal(signal.SIGINT, previous)

    def send_commands(self, commands: list[str] | tuple[str, ...]) -> None:
        """Send a few commands (numbered) outside a print: a console, a test."""
        program = Program("<commands>", tuple(commands), tuple(range(1, len(commands) + 1)),
                          tuple(0.0 for _ in commands), frozenset())
        self.stream(program)


@contextlib.contextmanager
def _noop() -> Iterator[None]:
    yield

"""Leaving and re-entering the stream: cancel, emergency stop, pause, stop signals, reconnect.

A cancel finishes the lines in flight and sends the cancel sequence; a pause
parks the machine and restores its state on resume; after a dropped link or
a firmware restart the stream resumes after the last acknowledged command
(what the host cannot know there is listed in the :mod:`machine_io.host`
docstring). Every signal that stops a process short of SIGKILL
(:data:`STOP_SIGNALS`: Ctrl-C, ``kill``, a closed terminal, Ctrl-\\) is a
cancel, and a second one an emergency stop: a host that simply died would
leave the heaters on with the motion stopped mid-layer. Mixed into
:class:`machine_io.host.Host`.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Callable
from typing import Any

import serial

from machine_io.machine_state import restore_commands, state_at
from machine_io.protocol import command_code, parse_reply
from machine_io.resend import StopStreaming
from machine_io.session import Progress
from machine_io.transport import LineReader
from printability.base.errors import PrinterError

__all__ = ["STOP_SIGNALS", "InterruptsMixin"]

# Signals that end a process unless handled (SIGKILL and SIGSTOP cannot be): each one cancels
# the stream cleanly (lines in flight finish, then the cancel sequence), a second one sends M112.
STOP_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT")
    if hasattr(signal, name))


class InterruptsMixin:
    """Cancel, pause, SIGINT and reconnection of :class:`machine_io.host.Host`."""

    def _finish_cancel(self) -> None:
        if self._emergency.is_set():
            self._emergency_stop_now()
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
        if self._emergency.is_set():  # a second signal while the lines in flight finished
            self._emergency_stop_now()
            return
        if self._fatal:
            return
        before = self._program_acked()
        self._inject(self.config.cancel_gcode, before)
        last = len(self._frames) - 1
        # The cancel sequence is sent even though _cancel is set: it is not program text.
        self._drain(self.config.reply_timeout * 4)
        if self._emergency.is_set():
            self._emergency_stop_now()
        elif (self.config.cancel_gcode and self._acked < last and not self._restarted
              and not self._fatal):
            # The printer did not take the cancel sequence in time (a long command still
            # running, a link that stopped answering): M112 goes through Marlin's emergency
            # parser even with a full queue, and a halted printer has its heaters off.
            self._note(f"the cancel sequence was not acknowledged within "
                       f"{self.config.reply_timeout * 4:g} s")
            self._emergency_stop_now()

    def _emergency_stop_now(self) -> None:
        self._send_emergency()
        if self._stop_reason is None or self._stop_reason == "cancelled":
            self._stop_reason = "emergency stop (M112)"

    def _leave_safe(self) -> None:
        """Cancel after an exception nobody expected ended the stream (a display that cannot
        write, a bug in a callback): the printer must not be left heating mid-layer."""
        self._cancel.set()
        with contextlib.suppress(Exception):
            self._finish_cancel()

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
                    raise StopStreaming
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
        acked = self._program_acked()
        if acked == self._acked_at_reconnect:
            self._reconnects_in_row += 1
        else:
            self._acked_at_reconnect, self._reconnects_in_row = acked, 1
        if self._reconnects_in_row > self.config.max_reconnects:
            self._stop_reason = self._reconnect_failure = (
                f"the {'link dropped' if reopen else 'firmware restarted'} "
                f"{self._reconnects_in_row} times in a row without a command being acknowledged "
                f"in between (limit {self.config.max_reconnects}): the printer is resetting in "
                f"a loop (power supply, firmware crash) or another program holds the port")
            return False
        self._reconnects += 1
        if reopen:
            self._note("the link was lost: reconnecting")
            if not self._reopen(timeout):
                self._stop_reason = self._reconnect_failure = (
                    f"the port could not be reopened within {timeout:g} s")
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

    def _install_signals(self) -> dict[int, Any]:
        """Turn each of :data:`STOP_SIGNALS` into a cancel while streaming (main thread only:
        Python runs handlers there); returns the handlers to put back."""
        if threading.current_thread() is not threading.main_thread():
            return {}

        def handler(signum: int, frame_: Any) -> None:
            # Only flags: the streaming loop sees them within a tenth of a second, and a
            # handler that wrote to the port could cut a line in half.
            self.interrupted = True
            if self.interrupted_by is None:
                self.interrupted_by = signal.Signals(signum).name
            if self._cancel.is_set():
                self._emergency.set()
            self._cancel.set()

        previous: dict[int, Any] = {}
        for signum in STOP_SIGNALS:
            try:
                previous[signum] = signal.signal(signum, handler)
            except (ValueError, OSError):
                continue
        return previous

    @staticmethod
    def _restore_signals(previous: dict[int, Any]) -> None:
        for signum, handler in previous.items():
            with contextlib.suppress(ValueError, OSError):
                # None: the handler was not set from Python; the default is what it did.
                signal.signal(signum, signal.SIG_DFL if handler is None else handler)

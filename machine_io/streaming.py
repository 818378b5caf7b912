"""The streaming loop: send a program to the end and prove the firmware accepted it.

:meth:`StreamingMixin.stream` drives the line machine
(:mod:`machine_io.resend`) with the program's commands, turns pause, cancel,
restarts and link failures into their handlers (:mod:`machine_io.interrupts`),
and ends only once the last line is provably accepted. Mixed into
:class:`machine_io.host.Host`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import serial

from machine_io.machine_state import restore_commands, state_at
from machine_io.program import Program, check_line_lengths
from machine_io.resend import StopStreaming
from machine_io.session import Progress, StreamReport
from printability.base.errors import InputError, PrinterError

__all__ = ["StreamingMixin"]

_BARRIER = "M105"


class StreamingMixin:
    """:meth:`stream` and its loop, for :class:`machine_io.host.Host`."""

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
            (:meth:`cancel`, ``//action:cancel``, or a stop signal: Ctrl-C,
            SIGTERM, SIGHUP, SIGQUIT, see :attr:`interrupted_by`) returns a
            report with ``stopped`` set.

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
        self._check_line_lengths(program)
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
        previous_handlers = self._install_signals()
        resume_path = Path(resume_file) if resume_file is not None else None
        try:
            failure = self._stream_loop(program, on_progress, resume_path, t0)
        except BaseException:
            # Whatever ended the loop unexpectedly (a progress callback that raised, a
            # KeyboardInterrupt outside the main thread's handler), the printer is heating
            # with its motion stopped: leave it safe before the exception goes on.
            if not self._cancel_done:
                self._cancel_done = True
                self._leave_safe()
            raise
        finally:
            self._restore_signals(previous_handlers)
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
    def _stream_loop(self, program: Program, on_progress: Callable[[Progress], None] | None,
                     resume_path: Path | None, t0: float) -> str | None:
        """Send, pause, cancel and recover until the program is done or cannot go on; why
        it stopped short (None: it did not), reporting progress and saving the resume file
        on the way."""
        last_progress = 0.0
        last_save = t0
        failure: str | None = None
        state = "streaming"
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
            except StopStreaming:
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
                failure = (f"the link to the printer failed ({exc})"
                           + (f": {self._reconnect_failure}" if self._reconnect_failure
                              else " and could not be reopened"))
                break
            now = time.monotonic()
            if on_progress is not None and now - last_progress >= 0.1:
                last_progress = now
                on_progress(self._progress(state))
            if resume_path is not None and now - last_save >= 2.0:
                last_save = now
                self._save_resume(resume_path)
        return failure

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
            except StopStreaming:
                return

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

    def _check_line_lengths(self, program: Program) -> None:
        # Marlin cuts a line past its MAX_CMD_SIZE (HostConfig.max_line_length); Klipper reads
        # a whole line of any length from its pseudo-terminal (its own start G-code registers
        # a rotary axis in about 100 bytes)
        if self.firmware.cuts_long_lines:
            check_line_lengths(program, self.config.max_line_length)

    def send_commands(self, commands: list[str] | tuple[str, ...]) -> None:
        """Send a few commands (numbered) outside a print: a console, a test."""
        program = Program("<commands>", tuple(commands), tuple(range(1, len(commands) + 1)),
                          tuple(0.0 for _ in commands), frozenset())
        self.stream(program)


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
called from another thread or a signal handler. While streaming in the main
thread, every signal that would end the process short of SIGKILL — SIGINT
(Ctrl-C), SIGTERM (``kill``, a service manager), SIGHUP (the terminal
closed), SIGQUIT — is turned into a clean cancel (the lines in flight finish,
then the cancel sequence turns heaters, fan and motors off); a second one
sends ``M112``. Any other exception that ends the stream (a display that can
no longer write, say) also sends the cancel sequence before it propagates.

The class is assembled from one mixin per responsibility:
:mod:`machine_io.connection` (port, banner, handshake, queries),
:mod:`machine_io.resend` (line history, send window, replies, resends),
:mod:`machine_io.streaming` (the loop and the end-of-file proof),
:mod:`machine_io.interrupts` (cancel, pause, Ctrl-C, reconnect) and
:mod:`machine_io.reporting` (progress, report, resume file).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator
from typing import Any

from machine_io.connection import ConnectionMixin, Heard
from machine_io.interrupts import InterruptsMixin
from machine_io.protocol import FirmwareInfo
from machine_io.reporting import ReportingMixin
from machine_io.resend import ResendMixin
from machine_io.session import (
    DEFAULT_CANCEL_GCODE,
    HostConfig,
    Progress,
    StreamReport,
    Transcript,
)
from machine_io.streaming import StreamingMixin
from machine_io.transport import LineReader

__all__ = [
    "DEFAULT_CANCEL_GCODE",
    "Host",
    "HostConfig",
    "Progress",
    "StreamReport",
    "Transcript",
]

_DEFAULT_CONFIG = HostConfig()  # frozen: safe to share


class Host(StreamingMixin, InterruptsMixin, ReportingMixin, ResendMixin, ConnectionMixin):
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
        self._connect_deadline: float | None = None  # while connecting: when to give up
        self._heard = Heard()
        self.interrupted = False
        """True once a signal (Ctrl-C, SIGTERM, SIGHUP, SIGQUIT) cancelled a stream."""
        self.interrupted_by: str | None = None
        """Name of the first signal that cancelled a stream (``"SIGTERM"``...), or None."""
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


@contextlib.contextmanager
def _noop() -> Iterator[None]:
    yield

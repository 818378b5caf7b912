"""What a streaming session is set up with and what it reports.

:class:`HostConfig` (how the host talks to the printer), :class:`Progress`
(snapshots for displays), :class:`StreamReport` (what happened) and
:class:`Transcript` (every line sent and received). The host itself is
:class:`machine_io.host.Host`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from machine_io.protocol import FirmwareInfo
from printability.base.errors import InputError, PrintabilityOSError
from printability.base.options import EXTRUDER_ERROR_POLICIES, STREAM_MODES

__all__ = ["DEFAULT_CANCEL_GCODE", "HostConfig", "Progress", "StreamReport", "Transcript"]

DEFAULT_CANCEL_GCODE: tuple[str, ...] = ("M104 S0", "M140 S0", "M107", "M84")


@dataclass(frozen=True)
class HostConfig:
    """How the host talks to the printer.

    Attributes
    ----------
    mode
        One of :data:`printability.options.STREAM_MODES`.
    error_policy
        What a firmware ``Error:`` does, one of
        :data:`printability.options.EXTRUDER_ERROR_POLICIES`.
    baud
        Baud rate, bits/s.
    banner_timeout
        How long to wait for the ``start`` banner after opening, s (a printer
        that does not reset on connect sends none; the handshake follows anyway).
    handshake_timeout, handshake_attempts
        Per-attempt wait for the ``M110`` reply, s, and the number of attempts.
    connect_timeout
        Overall limit of a connection (banner, handshake, capability queries; the
        handshake of a reconnection), s: a board that keeps talking without ever
        answering (a reset loop, noise at a wrong baud rate) is given up on then.
    reply_timeout
        Silence after which an unanswered line is retransmitted, s. Any reply
        to the lines in flight (``ok``, ``busy:``, ``Resend``, errors, a heating
        wait's temperature reports) restarts the clock; temperature auto-reports
        (M155) do not, or a lost ``ok`` would be waited for for ever.
    long_timeout
        The same for long commands (homing, heating waits, dwell...), s.
    keepalive_timeout
        The same for long commands once the firmware has shown that it sends
        ``busy:`` keepalives while it works (Marlin's HOST_KEEPALIVE_FEATURE),
        s; at least four keepalive intervals (an ``M113 S<n>`` in the file sets
        the interval, ``M113 S0`` turns this off and ``long_timeout`` applies).
        Before the firmware has shown whether it sends keepalives, a long
        command silent this long is retransmitted once without counting as a
        timeout (the line may have been lost; if it was not, the firmware
        refuses the copy by its line number).
    resend_ok_timeout
        A ``Resend`` not followed by ``ok`` within this time is treated as if
        it had been (firmwares that never send it), s.
    confirm_timeout
        After a timeout, a refused out-of-order line whose cause is unclear
        leads to a retransmission only if the requested line is not
        acknowledged within this time, s.
    max_resends
        Genuine resend requests of the same line in a row before stopping.
    max_timeouts
        Timeouts in a row without a single reply before declaring the printer lost.
    rx_buffer
        Firmware receive buffer, bytes (Marlin RX_BUFFER_SIZE 128, one kept free).
    max_window
        Most lines in flight in send-ahead mode.
    max_line_length
        Longest framed line, bytes (Marlin MAX_CMD_SIZE).
    check_axes
        Refuse a program that drives a rotary axis the firmware does not report.
    cancel_gcode
        Sent after a cancel (heaters, fan and motors off).
    pause_gcode
        Sent when a pause takes effect (e.g. a lift); on resume the position,
        angle, E, modes and feed rate are restored if it is not empty.
    reconnect_timeout
        After the link drops, keep trying to reopen the port this long, s (0: never).
    max_reconnects
        Reconnections (a dropped link, a firmware restart) in a row with no
        command acknowledged between them before giving up: a board in a boot
        loop would otherwise be reconnected to for ever.
    home_on_restore
        After a firmware restart, home X and Y before travelling back.
    end_barrier
        Without ADVANCED_OK, end with a numbered ``M105`` whose reply proves
        that every line was accepted.
    """

    mode: str = "auto"
    error_policy: str = "stop"
    baud: int = 250000
    banner_timeout: float = 3.0
    handshake_timeout: float = 2.0
    handshake_attempts: int = 3
    connect_timeout: float = 60.0
    reply_timeout: float = 5.0
    long_timeout: float = 1800.0
    keepalive_timeout: float = 10.0
    resend_ok_timeout: float = 1.0
    confirm_timeout: float = 0.5
    max_resends: int = 10
    max_timeouts: int = 4
    rx_buffer: int = 127
    max_window: int = 32
    max_line_length: int = 96
    check_axes: bool = True
    cancel_gcode: tuple[str, ...] = DEFAULT_CANCEL_GCODE
    pause_gcode: tuple[str, ...] = ()
    reconnect_timeout: float = 30.0
    max_reconnects: int = 5
    home_on_restore: bool = True
    end_barrier: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "mode", STREAM_MODES.check(self.mode))
        object.__setattr__(self, "error_policy", EXTRUDER_ERROR_POLICIES.check(self.error_policy))
        for name in ("banner_timeout", "handshake_timeout", "reply_timeout", "long_timeout",
                     "keepalive_timeout", "resend_ok_timeout", "confirm_timeout",
                     "reconnect_timeout", "connect_timeout"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v >= 0):
                raise InputError(f"{name} must be a non-negative number of seconds; got {v!r}")
        for name in ("baud", "handshake_attempts", "max_resends", "max_timeouts", "rx_buffer",
                     "max_window", "max_line_length", "max_reconnects"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise InputError(f"{name} must be a positive integer; got {v!r}")


@dataclass(frozen=True)
class Progress:
    """A snapshot for progress displays.

    Attributes
    ----------
    done, total
        Program commands acknowledged / in the program.
    seconds_done, seconds_total
        Estimated motion time of those commands, s.
    elapsed
        Wall time since streaming began, s.
    temperatures
        Last reported ``{name: (actual, target)}``, °C.
    state
        ``streaming``, ``paused``, ``cancelling``, ``reconnecting``, ``done``.
    resends
        Resend requests honoured so far.
    """

    done: int
    total: int
    seconds_done: float
    seconds_total: float
    elapsed: float
    temperatures: dict[str, tuple[float, float | None]]
    state: str
    resends: int

    @property
    def eta(self) -> float | None:
        """Remaining time, s: the file's own motion estimate, rescaled by the pace so far.

        None while unknown: before a second has passed or a command was
        acknowledged, and when the estimate is not a finite non-negative number
        (a file whose feed rates make its motion time overflow).
        """
        if self.total and self.done >= self.total:
            return 0.0
        remaining = self.seconds_total - self.seconds_done
        eta: float | None = None
        if self.seconds_done > 1.0 and self.elapsed > 1.0:
            eta = remaining * (self.elapsed / self.seconds_done)
        elif self.total and self.done and self.elapsed > 1.0:
            eta = self.elapsed * (self.total - self.done) / self.done
        if eta is None or not math.isfinite(eta) or eta < 0:
            return None
        return eta


@dataclass(frozen=True)
class StreamReport:
    """What happened during one streaming session.

    Attributes
    ----------
    source
        The program streamed.
    port
        The port.
    firmware
        What the firmware said of itself.
    mode
        ``ping-pong`` or ``send-ahead`` (as used).
    total
        Commands in the program.
    start
        0-based index of the first command of this session.
    acknowledged
        Commands of the program the firmware has acknowledged (index of the
        next command to send), i.e. the program ran up to ``acknowledged − 1``.
    completed
        Every command was acknowledged.
    stopped
        Why streaming stopped early (None when completed).
    lines_sent
        Numbered lines transmitted, retransmissions included.
    resends
        Genuine resend requests honoured.
    stale_resends
        Resend requests recognised as stale and ignored.
    timeouts
        Retransmissions after silence.
    reconnects
        Times the link was reopened.
    elapsed
        Wall time, s.
    bytes_sent
        Bytes written to the port.
    injected
        Commands the host added, as ``(program index before which they ran, commands)``:
        handshake queries excluded; restore sequences, pause/cancel sequences and
        the end barrier included.
    events
        Notable events in order (firmware errors, restarts, pauses).
    temperatures
        Last reported temperatures.
    in_doubt
        Per firmware restart, ``(first program index, count)`` of the commands that
        were sent but not acknowledged when it restarted and were sent again after
        it: any of the first of them may have run twice (their ``ok`` lost on the
        way, say). Nothing on the wire can tell.
    """

    source: str
    port: str
    firmware: FirmwareInfo
    mode: str
    total: int
    start: int
    acknowledged: int
    completed: bool
    stopped: str | None
    lines_sent: int
    resends: int
    stale_resends: int
    timeouts: int
    reconnects: int
    elapsed: float
    bytes_sent: int
    injected: tuple[tuple[int, tuple[str, ...]], ...] = ()
    events: tuple[str, ...] = ()
    temperatures: dict[str, tuple[float, float | None]] = field(default_factory=dict)
    in_doubt: tuple[tuple[int, int], ...] = ()

    @property
    def resend_ratio(self) -> float:
        """Resend requests honoured per numbered line transmitted."""
        return self.resends / self.lines_sent if self.lines_sent else 0.0

    @property
    def lines_per_second(self) -> float:
        return (self.acknowledged - self.start) / self.elapsed if self.elapsed > 0 else 0.0

    def to_json(self) -> dict[str, Any]:
        return {
            "source": self.source, "port": self.port, "firmware": self.firmware.to_json(),
            "mode": self.mode, "total": self.total, "start": self.start,
            "acknowledged": self.acknowledged, "completed": self.completed,
            "stopped": self.stopped, "lines_sent": self.lines_sent, "resends": self.resends,
            "resend_ratio": self.resend_ratio, "stale_resends": self.stale_resends,
            "timeouts": self.timeouts, "reconnects": self.reconnects, "elapsed": self.elapsed,
            "bytes_sent": self.bytes_sent,
            "injected": [[i, list(c)] for i, c in self.injected],
            "events": list(self.events),
            "temperatures": {k: list(v) for k, v in self.temperatures.items()},
            "in_doubt": [list(d) for d in self.in_doubt],
        }


class Transcript:
    """A log of every line sent and received, with times (like OctoPrint's serial.log).

    Parameters
    ----------
    path
        File to write; None keeps nothing.
    """

    def __init__(self, path: str | Path | None) -> None:
        self.path = Path(path) if path is not None else None
        self._fh: TextIO | None = None
        self._t0 = time.monotonic()
        if self.path is not None:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self._fh = open(self.path, "w", encoding="utf-8", errors="replace")
            except OSError as exc:
                raise PrintabilityOSError(
                    f"{self.path}: cannot write the transcript ({exc.strerror})") from None

    def write(self, direction: str, text: str) -> None:
        """Record one line; ``direction`` is ``Send``, ``Recv`` or ``Note``."""
        if self._fh is not None:
            self._fh.write(f"{time.monotonic() - self._t0:10.4f} {direction}: {text}\n")

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None

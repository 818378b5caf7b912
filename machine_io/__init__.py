"""The serial host: stream G-code to a Marlin-like printer and lose nothing.

It speaks bytes and G-code lines only (docs/design.md §1): nothing here knows of
geometry. The pieces:

- :mod:`machine_io.protocol` — framing (line numbers, checksums) and reply parsing;
- :mod:`machine_io.program` — a G-code file made ready to send, machine state at
  any line (for resuming), a motion-time estimate (for the ETA);
- :mod:`machine_io.transport` — opening a device, pty or pyserial URL; fast line reads;
- :mod:`machine_io.host` — the protocol state machine: handshake, capabilities,
  ping-pong and send-ahead streaming, resends, timeouts, pause/resume/cancel,
  reconnect and resume; :class:`Host` is assembled from
  :mod:`machine_io.connection`, :mod:`machine_io.resend`,
  :mod:`machine_io.streaming`, :mod:`machine_io.interrupts` and
  :mod:`machine_io.reporting`;
- :mod:`machine_io.display` — progress for people: a live bar in a terminal, a few plain
  lines elsewhere.

>>> from machine_io import Host, HostConfig, load_program   # doctest: +SKIP
>>> with Host("/dev/ttyUSB0", config=HostConfig(baud=115200)) as host:  # doctest: +SKIP
...     host.connect()
...     report = host.stream(load_program("part.gcode"))
"""

from __future__ import annotations

from machine_io.host import Host
from machine_io.program import (
    MachineState,
    Program,
    executed_as_streamed,
    load_program,
    parse_program,
    restore_commands,
    state_at,
)
from machine_io.protocol import FirmwareInfo, checksum, frame, parse_reply
from machine_io.session import (
    DEFAULT_CANCEL_GCODE,
    HostConfig,
    Progress,
    StreamReport,
    Transcript,
)
from machine_io.transport import open_port

__all__ = [
    "DEFAULT_CANCEL_GCODE",
    "FirmwareInfo",
    "Host",
    "HostConfig",
    "MachineState",
    "Program",
    "Progress",
    "StreamReport",
    "Transcript",
    "checksum",
    "executed_as_streamed",
    "frame",
    "load_program",
    "open_port",
    "parse_program",
    "parse_reply",
    "restore_commands",
    "state_at",
]

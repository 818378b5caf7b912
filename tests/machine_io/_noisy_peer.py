"""A serial peer that never stops talking and never answers: a board in a boot loop, or
protocol-like noise (echo, busy, temperature, error lines) without a ``start`` or an ``ok``.

It runs in a thread on the master side of a pty, like :mod:`_fake_marlin`; what the host
writes is kept in ``received``.
"""

from __future__ import annotations

import itertools
import os
import pty
import select
import threading
import time
import tty
from collections.abc import Sequence

NOISE = ("echo:busy: processing", "T:21.3 /0.0 B:20.9 /0.0 @:0 B@:0",
         "Error:Printer halted. kill() called!", "echo:SD init fail", "//action:notification x")
BOOT_LOOP = ("start", "echo:Marlin 2.1.2", "echo: Last Updated: 2023-01-01",
             "echo:Hardcoded Default Settings Loaded")


class NoisyPeer:
    """Writes ``lines`` over and over, ``interval`` seconds apart, until stopped.

    Parameters
    ----------
    lines
        What it says, in a loop.
    interval
        Pause between lines, s (0: as fast as the pty takes them).
    newline
        Line terminator (``b""``: noise without any line end).
    """

    def __init__(self, lines: Sequence[str] = NOISE, *, interval: float = 0.005,
                 newline: bytes = b"\n") -> None:
        self.master, slave = pty.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        self._slave = slave
        self.lines = [line.encode() + newline for line in lines]
        self.interval = interval
        self.received = bytearray()
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        for data in itertools.cycle(self.lines):
            if self._stop.is_set():
                return
            try:
                while select.select([self.master], [], [], 0)[0]:
                    self.received += os.read(self.master, 4096)
                if select.select([], [self.master], [], 0.05)[1]:
                    os.write(self.master, data)
                    self.sent += 1
            except OSError:
                return
            if self.interval:
                time.sleep(self.interval)

    def __enter__(self) -> NoisyPeer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

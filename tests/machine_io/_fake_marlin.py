"""A tiny scripted Marlin for the host's unit tests (not the simulator).

It runs in a thread on the master side of a pty; the host opens the slave
path like a real port. It implements just the protocol: banner, ``M110``,
line numbers and checksums with ``Error``/``Resend``/``ok``, ADVANCED_OK,
M115/M114/M105 replies, and faults scripted by line number (so tests are
deterministic): ``corrupt`` (the line arrives garbled), ``drop`` (the line is
lost), ``drop_ok``, ``dup_ok``, ``busy`` (busy lines before the ok), ``error``
(a firmware ``Error:`` line), ``silent`` (never answer again); lines in
``always_corrupt`` arrive garbled every time. ``executed``
records every command accepted, in order — what the tests compare with the file.
"""

from __future__ import annotations

import os
import pty
import select
import threading
import time
import tty
from dataclasses import dataclass, field


def _checksum(data: bytes) -> int:
    cs = 0
    for b in data:
        cs ^= b
    return cs


@dataclass
class FakeMarlin:
    advanced_ok: bool = False
    ok_after_resend: bool = True
    banner: bool = True
    axes: str = "XYZ"
    buffer_slots: int = 4
    name: str = "Marlin 2.1.2 (fake)"
    extra_caps: dict[str, int] = field(default_factory=dict)
    faults: dict[int, list[str]] = field(default_factory=dict)
    always_corrupt: frozenset[int] = frozenset()
    answer: bool = True
    executed: list[str] = field(default_factory=list)
    received: list[bytes] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.master, slave = pty.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        self._slave = slave
        self.last_n = 0
        self._stop = threading.Event()
        self._silent = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._fired: set[tuple[int, str]] = set()
        self.resend_requests = 0  # Resend lines sent (one per corrupted or out-of-order line)

    def start(self) -> FakeMarlin:
        if self.banner:
            self._send("start")
            self._send("echo:Marlin fake")
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        # Keep what the host wrote just before closing (an M112, say): the reader thread may
        # have stopped before the last bytes arrived.
        tail = b""
        while select.select([self.master], [], [], 0.05)[0]:
            try:
                chunk = os.read(self.master, 4096)
            except OSError:
                break
            if not chunk:
                break
            tail += chunk
        self.received.extend(line for line in tail.split(b"\n") if line)
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> FakeMarlin:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ----------------------------------------------------------------
    def _send(self, text: str) -> None:
        os.write(self.master, text.encode() + b"\n")

    def _fault(self, n: int, kind: str) -> bool:
        if kind in self.faults.get(n, ()) and (n, kind) not in self._fired:
            self._fired.add((n, kind))
            return True
        return False

    def _ok(self, n: int | None) -> None:
        if self.advanced_ok:
            head = f"ok N{n}" if n is not None else "ok"
            self._send(f"{head} P15 B{self.buffer_slots - 1}")
        else:
            self._send("ok")

    def _resend(self, reason: str) -> None:
        self.resend_requests += 1
        self._send(f"Error:{reason}, Last Line: {self.last_n}")
        self._send(f"Resend: {self.last_n + 1}")
        if self.ok_after_resend:
            self._send("ok")

    def _run(self) -> None:
        buf = b""
        while not self._stop.is_set():
            r, _, _ = select.select([self.master], [], [], 0.05)
            if not r:
                continue
            try:
                chunk = os.read(self.master, 4096)
            except OSError:
                return
            buf += chunk
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                self.received.append(line)
                if self.answer and not self._silent:
                    self._line(line.decode(errors="replace").strip())

    def _line(self, text: str) -> None:
        if not text:
            return
        n = None
        cmd = text
        if text.startswith("N"):
            head = text.partition(" ")[0]
            body, star, cs = text.rpartition("*")
            n = int(head[1:])
            if self._fault(n, "drop"):
                return
            if self._fault(n, "restart"):  # the board resets on this line: it is lost
                self.last_n = 0
                self._send("start")
                self._send("echo:Marlin fake")
                return
            if (n in self.always_corrupt or self._fault(n, "corrupt") or not star
                    or _checksum(body.encode()) != int(cs)):
                self._resend("checksum mismatch")
                return
            cmd = body.partition(" ")[2]
            if cmd.startswith("M110"):
                self.last_n = n
                self._ok(n)
                return
            if n != self.last_n + 1:
                self._resend("Line Number is not Last Line Number+1")
                return
            self.last_n = n
        if n is not None and self._fault(n, "silent"):
            self._silent = True
            return
        self.executed.append(cmd)
        if n is not None and self._fault(n, "busy"):
            self._send("echo:busy: processing")
            time.sleep(0.05)
            self._send("echo:busy: processing")
        if n is not None and self._fault(n, "error"):
            self._send("Error:Heater failure (fake)")
        code = cmd.split()[0].upper() if cmd else ""
        if code == "M115":
            self._send(f"FIRMWARE_NAME:{self.name} SOURCE_CODE_URL:x PROTOCOL_VERSION:1.0 "
                       f"MACHINE_TYPE:Fake EXTRUDER_COUNT:1 AXIS_COUNT:{len(self.axes)}")
            self._send(f"Cap:ADVANCED_OK:{int(self.advanced_ok)}")
            for k, v in self.extra_caps.items():
                self._send(f"Cap:{k}:{v}")
        elif code == "M114":
            pos = " ".join(f"{a}:0.00" for a in self.axes)
            self._send(f"{pos} E:0.00 Count {pos}")
        elif code == "M105":
            self._send("ok T:20.0 /0.0 B:20.0 /0.0 @:0 B@:0")
            return
        if n is not None and self._fault(n, "drop_ok"):
            return
        self._ok(n)
        if n is not None and self._fault(n, "dup_ok"):
            self._ok(n)

"""Transports of the virtual printer: a pseudo-terminal, TCP on loopback, and in-process.

All three share :class:`Link`, a thread-safe wrapper of one :class:`Firmware`
that keeps its clock (simulated or real) and interprets the link markers
(:class:`Stall`, :class:`Disconnect`) the firmware emits:

- **pty** (:class:`PtyServer`): ``os.openpty``; hosts open the slave path as a
  serial port. Opening the port resets the board and sends the banner, like
  an Arduino whose DTR line resets it (the open is seen as the end of the
  master's hang-up state). A ``disconnect`` fault resets the board and greets
  again on the same path (the port stays, as with a board behind a USB-UART
  bridge).
- **TCP** (:class:`TcpServer`): one client at a time on 127.0.0.1, usable as
  pyserial's ``socket://127.0.0.1:PORT``; a ``disconnect`` fault closes the
  connection, the next connection gets the reset banner.
- **in-process**: the ``printsim://`` pyserial URL (:mod:`simulators.urlhandler`).

Baud pacing (``SimConfig.baud``): incoming bytes reach the firmware 10 bits
per byte after they were sent (simulated or real time); under the real clock
each line the firmware says reaches the host 10 bits per byte after the
return wire is free.

Real clock: as soon as bytes come in, the firmware is run ahead to the time
they finish arriving (:meth:`Firmware.run_until`) and its answers are held
until the time they would reach the host. The simulator's own computing thus
hides inside the wire time, as a board's does inside its UART's, and the
timing a host sees is the model's, not Python's.
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import select
import socket
import threading
import time
import tty
from collections import deque
from collections.abc import Callable

from printability.base.errors import PrintabilityOSError
from simulators.config import SimConfig
from simulators.firmware import Disconnect, Firmware, Stall

__all__ = ["Link", "PtyServer", "TcpServer"]


class Link:
    """One firmware behind a lock, with its clock and the link markers resolved.

    Parameters
    ----------
    config
        The simulator configuration.
    """

    def __init__(self, config: SimConfig) -> None:
        self.config = config
        self.firmware = Firmware(config)
        self.lock = threading.RLock()
        self._t0 = time.monotonic()
        self._stall_until = 0.0
        # what the firmware said, with the firmware time it said it at (real clock: s since _t0)
        self._held: deque[tuple[float, bytes | Stall | Disconnect]] = deque()
        self._out_free = 0.0  # when the return wire is free (real clock), s since _t0
        self.disconnected = False
        self.on_record: Callable[[], None] | None = None
        # simulated clock: the wall time (time.monotonic) of the next M155 report while the
        # host is silent (Firmware.idle_report); inf while auto-reports are off
        self._idle_report_at = math.inf

    @property
    def real(self) -> bool:
        return self.config.clock == "real"

    def _now(self) -> float:
        return time.monotonic() - self._t0

    def _pump(self) -> None:
        if time.monotonic() < self._stall_until:
            return  # a stalled firmware does nothing at all
        if self.real:
            fw = self.firmware
            fw.run_until(max(self._now(), fw.pending_until()))
        else:
            self.firmware.run_sim()
            self._idle_reports()

    def _idle_reports(self, *, host_spoke: bool = False) -> None:
        """Simulated clock: M155 reports on the wall clock while the host is silent."""
        interval = self.firmware.autoreport_interval
        wall = time.monotonic()
        if interval <= 0:
            self._idle_report_at = math.inf
        elif host_spoke or not math.isfinite(self._idle_report_at):
            self._idle_report_at = wall + interval
        elif wall >= self._idle_report_at:
            self.firmware.idle_report()
            self._idle_report_at = wall + interval

    def connect(self) -> None:
        """A host opened the link: reset and greet."""
        with self.lock:
            self.disconnected = False
            self._held.clear()
            self._stall_until = 0.0
            self._out_free = 0.0
            self._idle_report_at = math.inf
            self.firmware.connect()
            self._pump()

    def feed(self, data: bytes) -> None:
        """Bytes from the host."""
        with self.lock:
            if self.disconnected:
                return
            self.firmware.receive(data, self._now() if self.real else None)
            self._pump()
            if not self.real:
                self._idle_reports(host_spoke=True)

    def _take(self) -> None:
        for t, item in self.firmware.take_output_timed():
            if isinstance(item, bytes) and self.real and self.config.baud:
                # line by line: a host reads the first line before the last is on the wire
                self._held.extend((t, line) for line in item.splitlines(keepends=True))
            else:
                self._held.append((t, item))

    def _due(self, t: float, item: bytes | Stall | Disconnect) -> float:
        """Real clock: when ``item``, said at ``t``, has reached the host (s since _t0)."""
        if isinstance(item, bytes) and self.config.baud:
            return max(t, self._out_free) + len(item) * 10.0 / self.config.baud
        return t

    def read_available(self) -> bytes:
        """Bytes that have reached the host, up to the next stall or disconnect marker."""
        with self.lock:
            self._pump()
            self._take()
            out = bytearray()
            now = self._now()
            while self._held and time.monotonic() >= self._stall_until:
                t, item = self._held[0]
                if self.real:
                    due = self._due(t, item)
                    if due > now:
                        break
                if isinstance(item, bytes):
                    out += item
                    self._held.popleft()
                    if self.real:
                        self._out_free = due
                elif isinstance(item, Stall):
                    self._held.popleft()
                    self._stall_until = time.monotonic() + item.seconds
                else:  # Disconnect: what follows belongs to the next connection
                    if out:
                        break
                    self._held.popleft()
                    self.disconnected = True
                    break
            return bytes(out)

    def wait_time(self) -> float:
        """Seconds until the firmware next needs the clock (for select timeouts)."""
        with self.lock:
            stall = self._stall_until - time.monotonic()
            if stall > 0:
                return stall
            if not self.real:
                return 0.05
            now = self._now()
            t = self.firmware.next_event()
            if t <= now:
                # due but not moving (input waits for room in a full receive ring): poll
                # every millisecond rather than spin
                t = now + 0.001
            if self._held:
                t = min(t, self._due(*self._held[0]))
            return max(0.0, min(t - now, 0.05))

    def status(self) -> str:
        """The firmware's one-line status (see :meth:`Firmware.status_line`)."""
        with self.lock:
            return self.firmware.status_line()

    def close(self) -> None:
        """Finish: let the planner drain (for the print time) and write the record if asked."""
        with self.lock:
            self.firmware.drain()
            if self.config.record:
                self.firmware.write_record()


class _Server:
    def __init__(self, link: Link) -> None:
        self.link = link
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None
        self.on_event: Callable[[str], None] | None = None
        """Called from the server thread with a one-line message when a host connects or
        leaves and when the board resets; it must not block (``printability simulate``
        hands the lines to its main thread)."""

    def _event(self, message: str) -> None:
        if self.on_event is not None:
            # A message must never stop the printer.
            with contextlib.suppress(Exception):
                self.on_event(message)

    def start(self) -> _Server:
        self._thread = threading.Thread(target=self._guarded, name=type(self).__name__,
                                        daemon=True)
        self._thread.start()
        return self

    def _guarded(self) -> None:
        try:
            self._run()
        except BaseException as exc:  # reported by stop(); a server thread must not vanish
            self.error = exc

    def _run(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def stop(self, *, timeout: float = 5.0) -> None:
        """Stop the server thread, drain the planner and write the record if configured."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self._close()
        self.link.close()

    def _close(self) -> None:  # pragma: no cover - overridden
        pass

    def __enter__(self) -> _Server:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


_SPIN = 0.0003  # s: how long before an answer is due a server stops sleeping
_LISTEN = 0.0005  # s: how long after an answer it spins for the host's next line


def _select_timeout(wait: float, listen_until: float) -> float:
    """How long a server may block in ``select`` when the link next needs it in ``wait`` s.

    A sleeping thread wakes up ~0.1 ms late: an answer due within 2 ms is
    woken for early and spun for, and right after an answer the host's next
    line is spun for too (a board's UART interrupt has no wake-up latency).
    """
    if time.monotonic() < listen_until:
        return 0.0
    if wait < 0.002:
        return max(wait - _SPIN, 0.0)
    return wait


class PtyServer(_Server):
    """The printer on a pseudo-terminal; :attr:`path` is the port hosts open."""

    def __init__(self, link: Link, *, symlink: str | None = None) -> None:
        super().__init__(link)
        self.master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing: a serial line
        self.path = os.ttyname(slave)
        os.close(slave)  # the host's open is then seen as the end of the hang-up
        os.set_blocking(self.master, False)
        self.symlink = symlink
        if symlink:
            try:
                if os.path.islink(symlink):
                    os.unlink(symlink)
                os.symlink(self.path, symlink)
            except OSError as exc:
                os.close(self.master)
                raise PrintabilityOSError(f"{symlink}: cannot create the port link "
                                          f"({exc.strerror})") from None
        # True while a host has the port open. A close and reopen faster than the poll
        # interval (~10 ms) is not seen as a reset.
        self.connected = False

    def _run(self) -> None:
        link, poller = self.link, select.poll()
        poller.register(self.master, select.POLLIN)
        listen_until = 0.0
        while not self._stop.is_set():
            wait = link.wait_time()
            if wait < 0.002 or time.monotonic() < listen_until:
                # poll() counts whole milliseconds: short waits are timed by select()
                select.select([self.master], [], [], _select_timeout(wait, listen_until))
                wait = 0.0
            events = poller.poll(wait * 1000)
            hup = any(ev & select.POLLHUP for _, ev in events)
            if hup:
                if self.connected:
                    self._event(f"the host closed {self.path}")
                self.connected = False
                time.sleep(0.01)  # nobody has the port open: POLLHUP is level-triggered
                continue
            if not self.connected:
                self.connected = True
                link.connect()
                self._event(f"a host opened {self.path}: the board resets and greets it")
            if any(ev & select.POLLIN for _, ev in events):
                try:
                    data = os.read(self.master, 4096)
                except OSError as exc:
                    if exc.errno in (errno.EIO, errno.EAGAIN):
                        continue
                    raise
                link.feed(data)
            out = link.read_available()
            if link.disconnected:  # the board reset: same port, new banner
                link.connect()
                self._event("the board reset (disconnect fault) and greets the host again")
                out += link.read_available()
            if out:
                self._write(out)
                listen_until = time.monotonic() + _LISTEN

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view and not self._stop.is_set():
            try:
                n = os.write(self.master, view)
            except BlockingIOError:
                time.sleep(0.001)
                continue
            except OSError as exc:
                if exc.errno == errno.EIO:
                    return  # the host closed the port
                raise
            view = view[n:]

    def _close(self) -> None:
        try:
            os.close(self.master)
        except OSError:
            pass
        if self.symlink and os.path.islink(self.symlink):
            os.unlink(self.symlink)


class TcpServer(_Server):
    """The printer on a TCP port of 127.0.0.1; :attr:`url` is ``socket://127.0.0.1:PORT``."""

    def __init__(self, link: Link, *, port: int = 0) -> None:
        super().__init__(link)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.sock.bind(("127.0.0.1", port))
        except OSError as exc:
            self.sock.close()
            raise PrintabilityOSError(f"cannot listen on 127.0.0.1:{port} "
                                      f"({exc.strerror})") from None
        self.sock.listen(1)
        self.port = self.sock.getsockname()[1]
        self.url = f"socket://127.0.0.1:{self.port}"

    def _run(self) -> None:
        link = self.link
        while not self._stop.is_set():
            r, _, _ = select.select([self.sock], [], [], 0.05)
            if not r:
                continue
            conn, peer = self.sock.accept()
            with conn:
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                link.connect()
                self._event(f"a host connected from {peer[0]}:{peer[1]}: the board resets and "
                            f"greets it")
                self._serve(conn)
                self._event("the board reset (disconnect fault) and dropped the connection"
                            if link.disconnected else "the host disconnected")

    def _serve(self, conn: socket.socket) -> None:
        link = self.link
        listen_until = 0.0
        while not self._stop.is_set():
            r, _, _ = select.select([conn], [], [],
                                    _select_timeout(link.wait_time(), listen_until))
            if r:
                try:
                    data = conn.recv(4096)
                except OSError:
                    return
                if not data:
                    return  # the host closed the connection
                link.feed(data)
            out = link.read_available()
            if out:
                try:
                    conn.sendall(out)
                except OSError:
                    return
                listen_until = time.monotonic() + _LISTEN
            if link.disconnected:
                return  # drop the connection; the next one is greeted after a reset

    def _close(self) -> None:
        self.sock.close()

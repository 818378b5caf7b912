"""Opening a port and reading lines from it quickly.

A port is a device (``/dev/ttyUSB0``), a pty path (``/dev/pts/5``) or any
pyserial URL (``socket://127.0.0.1:5000``, ``printsim://…``, ``loop://``).
URL schemes that pyserial does not know are looked up in the packages of
:data:`URL_HANDLER_PACKAGES` (pyserial's own mechanism,
``serial.protocol_handler_packages``); the built-in simulator registers its
scheme there.

:class:`LineReader` replaces pyserial's ``readline``, which reads one byte per
system call: it reads whatever is waiting and splits lines itself. On a POSIX
device or pty it waits on the descriptor itself (one ``select`` and one
``read`` per burst): pyserial's ``read`` costs an ``ioctl`` for
``in_waiting``, a ``select`` on two descriptors and a read of the size asked
for, which in ping-pong streaming adds up to a measurable share of the
wire's line time.
"""

from __future__ import annotations

import errno
import os
import select
import time
from typing import Any

import serial

from printability.base.errors import PrintabilityOSError, excerpt

__all__ = ["URL_HANDLER_PACKAGES", "LineReader", "open_port"]

# Longest line kept whole, bytes: a firmware line is far shorter; noise without a line end
# (a wrong baud rate) is handed out in pieces of this size instead of piling up.
MAX_LINE = 65536
# Packages holding pyserial URL handlers (module ``<package>.protocol_<scheme>``).
URL_HANDLER_PACKAGES: tuple[str, ...] = ("simulators.urlhandler",)


def open_port(port: str, *, baud: int = 250000, timeout: float = 0.05) -> Any:
    """Open a serial port, a pty or a pyserial URL.

    Parameters
    ----------
    port
        Device path, pty path or URL (``scheme://…``).
    baud
        Baud rate (ignored by ptys and sockets).
    timeout
        Read timeout of one ``read`` call, s (the host polls with it).

    Returns
    -------
    serial.SerialBase
        An open port.

    Raises
    ------
    PrintabilityOSError
        The port does not exist, is busy, or cannot be opened; the message says which.
    """
    if "://" in port:
        for package in URL_HANDLER_PACKAGES:
            if package not in serial.protocol_handler_packages:
                serial.protocol_handler_packages.append(package)
        try:
            return serial.serial_for_url(port, baudrate=baud, timeout=timeout,
                                         write_timeout=10.0)
        except (serial.SerialException, ValueError, OSError) as exc:
            raise PrintabilityOSError(
                f"cannot open the printer port {excerpt(port)}: {str(exc)[:200]}. Check the URL "
                f"(pyserial URL schemes: socket://HOST:PORT, rfc2217://, loop://, and "
                f"printsim:// for the built-in simulator).") from None
    if not os.path.exists(port):
        raise PrintabilityOSError(
            f"the printer port {excerpt(port)} does not exist: is the printer plugged in and "
            f"switched on? Serial ports are usually /dev/ttyUSB0 or /dev/ttyACM0 on Linux, COM3 on "
            f"Windows; a simulator prints its port on the first line it writes.")
    try:
        return serial.Serial(port, baudrate=baud, timeout=timeout, write_timeout=10.0)
    except (serial.SerialException, OSError, ValueError) as exc:
        hint = ""
        if "ermission" in str(exc):
            hint = " Add your user to the group that owns the port (often 'dialout')."
        elif "busy" in str(exc).lower():
            hint = " Another program (a host, a slicer, ModemManager) holds it."
        raise PrintabilityOSError(f"cannot open the printer port {excerpt(port)}: "
                                  f"{str(exc)[:200]}.{hint}") from None


class LineReader:
    """Buffered line reading from a pyserial port.

    Parameters
    ----------
    port
        An open pyserial port whose ``timeout`` bounds one ``read``.
    """

    def __init__(self, port: Any) -> None:
        self.port = port
        self._buffer = bytearray()
        self._lines: list[bytes] = []
        self._fd: int | None = None
        if os.name == "posix" and isinstance(port, serial.Serial):
            try:
                self._fd = port.fileno()
            except (AttributeError, OSError, serial.SerialException):
                self._fd = None

    def _read_fd(self, fd: int, deadline: float) -> bytes:
        """One burst straight from the descriptor (pyserial opened it non-blocking)."""
        timeout = self.port.timeout if self.port.timeout is not None else 0.05
        wait = max(0.0, min(timeout, deadline - time.monotonic()))
        try:
            ready, _, _ = select.select([fd], [], [], wait)
            if not ready:
                return b""
            data = os.read(fd, 4096)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno in (errno.EINTR, errno.EAGAIN):
                return b""
            raise serial.SerialException(f"read failed: {exc}") from None
        if not data:  # pyserial's words for the same condition
            raise serial.SerialException("device reports readiness to read but returned no "
                                         "data (device disconnected or multiple access on "
                                         "port?)")
        return data

    def readline(self, deadline: float) -> bytes | None:
        """The next complete line without its terminator, or None if ``deadline`` passes.

        Parameters
        ----------
        deadline
            ``time.monotonic()`` value after which to give up, s.

        Raises
        ------
        OSError, serial.SerialException
            The port failed (the caller decides whether to reconnect).
        """
        while True:
            if self._lines:
                return self._lines.pop(0)
            if self._fd is not None:
                chunk = self._read_fd(self._fd, deadline)
            else:
                chunk = self.port.read(max(1, self.port.in_waiting))
            if chunk:
                self._buffer += chunk
                if b"\n" in chunk or b"\r" in chunk:
                    parts = self._buffer.replace(b"\r", b"\n").split(b"\n")
                    self._buffer = bytearray(parts.pop())
                    self._lines.extend(p for p in parts if p.strip())
                if len(self._buffer) > MAX_LINE:
                    self._lines.append(bytes(self._buffer))
                    self._buffer.clear()
                if self._lines:
                    continue
            if time.monotonic() >= deadline:
                return None

    def write(self, data: bytes) -> None:
        """Write all of ``data`` to the port (on a POSIX descriptor directly: pyserial
        follows every write with a ``select`` for its write timeout).

        Raises
        ------
        serial.SerialTimeoutException
            The port took no bytes for the port's ``write_timeout`` (10 s).
        serial.SerialException
            The port failed.
        """
        if self._fd is None:
            self.port.write(data)
            return
        view = memoryview(data)
        limit = self.port.write_timeout if self.port.write_timeout is not None else 10.0
        deadline = time.monotonic() + limit
        while view:
            try:
                n = os.write(self._fd, view)
            except BlockingIOError:
                n = 0
            except OSError as exc:
                if exc.errno == errno.EINTR:
                    continue
                raise serial.SerialException(f"write failed: {exc}") from None
            view = view[n:]
            if view:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise serial.SerialTimeoutException("Write timeout")
                select.select([], [self._fd], [], left)

    def pending(self) -> bool:
        """True if a complete line is already buffered."""
        return bool(self._lines)

    def clear(self) -> None:
        """Drop everything buffered (after a reconnect)."""
        self._buffer.clear()
        self._lines.clear()

"""``printsim://`` — the virtual printer as an in-process pyserial port.

Usage::

    import serial, simulators
    ser = serial.serial_for_url("printsim://?profile=marlin&nozzle=ellipse:major=0.8,minor=0.3"
                                "&faults=drop-ok@12&seed=3", timeout=1)
    ser.simulator         # the Link; ser.simulator.firmware is the Firmware

Query keys: ``profile``, ``machine``, ``nozzle``, ``clock`` (``sim`` default,
or ``real``), ``baud`` (wire pacing of what the host sends), ``faults``,
``seed``, ``record`` (path of the deposition record), and any
:class:`simulators.config.FirmwareProfile` field as ``fw.<field>=value`` (e.g.
``fw.planner_buffer=4``). The record is written when the port is closed.

Opening the port resets the board (DTR) and sends the banner. After a
``disconnect`` fault, reads and writes raise ``SerialException`` until the
host closes and reopens the port, which reconnects to the same (reset)
printer.
"""

from __future__ import annotations

import time
import urllib.parse

from serial.serialutil import PortNotOpenError, SerialBase, SerialException, Timeout

from printability.base.errors import PrintabilityError
from simulators.config import make_config
from simulators.transports import Link

__all__ = ["Serial"]

_INT_FIELDS = {"rx_buffer", "command_buffer", "planner_buffer", "max_line", "arc_min_segments"}
_BOOL_FIELDS = {"checksums", "advanced_ok", "ok_after_resend", "rx_overflow_drops"}


def _parse_url(url: str) -> dict[str, object]:
    parts = urllib.parse.urlsplit(url)
    if parts.scheme != "printsim":
        raise SerialException(f"expected a URL starting with printsim://; got {url!r}")
    kw: dict[str, object] = {}
    fw: dict[str, object] = {}
    for key, value in urllib.parse.parse_qsl(parts.query, keep_blank_values=True):
        if key.startswith("fw."):
            name = key[3:]
            try:
                if name in _BOOL_FIELDS:
                    fw[name] = value.lower() in ("1", "true", "yes", "on")
                elif name in _INT_FIELDS:
                    fw[name] = int(value)
                else:
                    fw[name] = float(value)
            except ValueError:
                raise SerialException(f"printsim URL: {key}= expects a number; "
                                      f"found {value!r}") from None
        elif key in ("profile", "machine", "nozzle", "clock", "faults", "record"):
            kw[key] = value
        elif key in ("baud", "seed"):
            try:
                kw[key] = int(value)
            except ValueError:
                raise SerialException(f"printsim URL: {key}= expects an integer; "
                                      f"found {value!r}") from None
        else:
            raise SerialException(f"printsim URL: unknown option {key!r}; expected profile, "
                                  f"machine, nozzle, clock, baud, faults, seed, record or "
                                  f"fw.<setting>")
    if fw:
        kw["firmware"] = fw
    return kw


class Serial(SerialBase):
    """A pyserial port whose other end is the simulator (see the module docstring)."""

    simulator: Link | None = None

    def open(self) -> None:
        if self.is_open:
            raise SerialException("Port is already open.")
        if self.simulator is None:
            try:
                self.simulator = Link(make_config(**_parse_url(self.portstr)))  # type: ignore[arg-type]
            except PrintabilityError as exc:
                raise SerialException(f"printsim URL: {exc}") from None
        self._rx = bytearray()
        self.is_open = True
        self.simulator.connect()

    def close(self) -> None:
        """Close the port; with ``record=PATH`` the planner is drained and the record written
        (a later reopen reconnects to the same printer and a later close rewrites it)."""
        if self.is_open and self.simulator is not None and self.simulator.config.record:
            self.simulator.close()
        self.is_open = False

    def _reconfigure_port(self) -> None:
        pass

    def _check(self) -> Link:
        if not self.is_open or self.simulator is None:
            raise PortNotOpenError()
        if self.simulator.disconnected:
            raise SerialException("device reports readiness to read but returned no data "
                                  "(device disconnected or multiple access on port?)")
        return self.simulator

    def _fill(self) -> None:
        link = self._check()
        self._rx += link.read_available()

    @property
    def in_waiting(self) -> int:
        self._fill()
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        link = self._check()
        timeout = Timeout(self._timeout)
        while len(self._rx) < size:
            self._fill()
            if len(self._rx) >= size or timeout.expired():
                break
            if link.disconnected:
                break
            time.sleep(min(max(link.wait_time(), 0.0005), 0.01, max(timeout.time_left(), 0)))
        data = bytes(self._rx[:size])
        del self._rx[:size]
        if not data and self.simulator is not None and self.simulator.disconnected:
            self._check()
        return data

    def write(self, data: bytes) -> int:
        link = self._check()
        data = bytes(data)
        link.feed(data)
        return len(data)

    def reset_input_buffer(self) -> None:
        self._check()
        self._rx.clear()

    def reset_output_buffer(self) -> None:
        self._check()

    def flush(self) -> None:
        self._check()

    def cancel_read(self) -> None:
        pass

    def cancel_write(self) -> None:
        pass

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True

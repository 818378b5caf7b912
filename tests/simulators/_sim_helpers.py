"""Test helpers: an independent checksum, a minimal reference host, stripped file commands."""

from __future__ import annotations

import functools
import operator
import re
from pathlib import Path

import serial

import simulators  # noqa: F401  (registers printsim://)

__all__ = ["MiniHost", "file_commands", "framed", "open_sim", "xor"]


def xor(text: str) -> int:
    """The Marlin/Printrun checksum computed independently of the simulator."""
    return functools.reduce(operator.xor, text.encode("ascii"), 0)


def framed(n: int, text: str) -> bytes:
    s = f"N{n} {text}"
    return f"{s}*{xor(s)}\n".encode("ascii")


def open_sim(query: str = "", **kw: object) -> serial.SerialBase:
    """A printsim:// port with the simulated clock; timeout 0 (replies are synchronous)."""
    url = "printsim://?" + query
    return serial.serial_for_url(url, timeout=kw.pop("timeout", 0), **kw)


def file_commands(path: Path, *, limit: int | None = None) -> list[str]:
    """Commands of a G-code file as a host sends them: ';' comments and blanks removed."""
    out = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for i, line in enumerate(fh):
            if limit is not None and i >= limit:
                break
            text = line.split(";", 1)[0].strip()
            if text:
                out.append(text)
    return out


_OK_N = re.compile(r"^ok N(-?\d+)")


class MiniHost:
    """A ping-pong reference host for the simulated clock (all replies are ready once a line
    is written): line numbers, checksums, Resend, and silence handled by resending the line.

    Recovery rules: ``Resend: k`` restarts from k; no ``ok`` at all (dropped line or
    dropped ok) resends the current line — an already executed one is then refused with
    'Line Number is not Last Line Number+1' and a Resend of the next. With ADVANCED_OK the
    ``ok N<n>`` is matched to its line so a duplicated ``ok`` cannot acknowledge the next one.
    """

    def __init__(self, ser: serial.SerialBase, *, max_steps: int = 1_000_000) -> None:
        self.ser = ser
        self.max_steps = max_steps
        self.transcript: list[str] = []
        self._buf = b""

    def _lines(self) -> list[str]:
        self._buf += self.ser.read(1 << 20)
        *done, self._buf = self._buf.split(b"\n")
        out = [d.decode("latin-1") for d in done]
        self.transcript.extend(out)
        return out

    def stream(self, commands: list[str]) -> None:
        self._lines()  # banner
        self.ser.write(framed(0, "M110 N0"))
        self._lines()
        n, steps = 1, 0
        while n <= len(commands):
            steps += 1
            if steps > self.max_steps:
                raise RuntimeError("mini host made no progress")
            self.ser.write(framed(n, commands[n - 1]))
            nxt = None
            acked = False
            for line in self._lines():
                if line.startswith("Resend:"):
                    nxt = int(line.split(":")[1])
                elif line.startswith("ok") and nxt is None:
                    m = _OK_N.match(line)
                    if m is None or int(m.group(1)) == n:
                        acked = True
            if nxt is not None:
                n = nxt
            elif acked:
                n += 1
            # silence: resend the same line

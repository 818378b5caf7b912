"""Helpers for tests that run the real ``printability`` entry point: the simulator in its own
process, a command inside a pseudo-terminal with a window size, and a minimal terminal that
turns what it wrote into the lines a person would see."""

from __future__ import annotations

import fcntl
import json
import os
import re
import select
import signal
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# The console script the README tells users to run (the venv's), not `python -m`: its start
# is what a user's terminal sees.
_SCRIPT = Path(sys.executable).with_name("printability")
PRINTABILITY = [str(_SCRIPT)] if _SCRIPT.exists() else [sys.executable, "-m", "printability"]
CANCEL = ["M104 S0", "M140 S0", "M107", "M84"]


def env(**extra: str) -> dict[str, str]:
    """The environment of a child: unbuffered, and without the variables that make rich
    guess a terminal size or colour support other than the real one."""
    out = {k: v for k, v in os.environ.items()
           if k not in ("COLUMNS", "LINES", "TTY_COMPATIBLE", "TTY_INTERACTIVE", "FORCE_COLOR",
                        "NO_COLOR", "JUPYTER_COLUMNS", "JUPYTER_LINES")}
    out["PYTHONUNBUFFERED"] = "1"
    out.update(extra)
    return out


class Simulator:
    """``printability simulate --pty --clock sim --record FILE`` in its own process (or
    ``clock="real"``).

    The port is the first line of its stdout; :meth:`stop` ends it with SIGTERM and
    returns its stderr; :meth:`log` reads the record it then writes.
    """

    def __init__(self, record: Path, *args: str, clock: str = "sim") -> None:
        self.record = record
        self.proc = subprocess.Popen(
            [*PRINTABILITY, "simulate", "--pty", "--clock", clock, "--record", str(record),
             "--duration", "300", *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env())
        self.port = self.proc.stdout.readline().strip()
        if not self.port.startswith("/dev/"):
            self.stop()
            raise AssertionError(f"the simulator did not start: {self.proc.stderr.read()}")
        self.stderr = ""

    def stop(self) -> str:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            _, self.stderr = self.proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, self.stderr = self.proc.communicate()
        return self.stderr

    def log(self) -> list[str]:
        """The numbered lines the printer ran, handshakes left out."""
        doc = json.loads(self.record.read_text())
        return [t for n, t in doc["log"] if n is not None and n >= 1
                and not t.startswith("M110")]

    def __enter__(self) -> Simulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def run_in_terminal(args: list[str], *, columns: int = 100, rows: int = 30,
                    timeout: float = 60.0) -> tuple[int | None, str]:
    """Run ``args`` with stdin, stdout and stderr on a new pseudo-terminal of the given
    size; returns (exit status or None if it had to be killed, everything it wrote)."""
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, columns, 0, 0))
    proc = subprocess.Popen(args, stdin=slave, stdout=slave, stderr=slave, cwd=ROOT,
                            env=env(TERM="xterm-256color"), start_new_session=True)
    os.close(slave)
    out = bytearray()
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.1)
            if ready:
                try:
                    chunk = os.read(master, 65536)
                except OSError:  # EIO: every process holding the terminal has exited
                    break
                if not chunk:
                    break
                out += chunk
            elif proc.poll() is not None:
                break
    finally:
        os.close(master)
        try:  # the terminal is closed once the child has exited, or about to
            status: int | None = proc.wait(max(1.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
            status = None
    return status, out.decode("utf-8", "replace")


_ESCAPE = re.compile(r"\x1b(?:\[([0-9;?]*)([@-~])|\][^\x07\x1b]*(?:\x07|\x1b\\)|[@-Z\\-_])")


def screen(text: str) -> list[str]:
    """The lines a terminal shows after ``text``: carriage returns, erased lines and cursor
    moves up applied (what rich's live display uses), colours and other controls dropped."""
    lines: list[list[str]] = [[]]
    row = col = 0
    i = 0
    while i < len(text):
        ch = text[i]
        if ch == "\x1b":
            m = _ESCAPE.match(text, i)
            if m is None:
                i += 1
                continue
            arg, cmd = m.group(1), m.group(2)
            if cmd == "A":  # cursor up
                row = max(0, row - int(arg or 1))
            elif cmd == "K":  # erase in line
                if arg == "2":
                    lines[row] = []
                else:
                    del lines[row][col:]
            elif cmd == "G":  # cursor to column
                col = max(0, int(arg or 1) - 1)
            i = m.end()
            continue
        if ch == "\r":
            col = 0
        elif ch == "\n":
            row += 1
            col = 0
            while len(lines) <= row:
                lines.append([])
        elif ch >= " ":
            line = lines[row]
            while len(line) < col:
                line.append(" ")
            if col < len(line):
                line[col] = ch
            else:
                line.append(ch)
            col += 1
        i += 1
    return ["".join(line).rstrip() for line in lines]
